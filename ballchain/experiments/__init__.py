"""The paper's experiments in simulation, each a ``run(...)`` returning a result dataclass.

One module per experiment; its ``run`` checks its inputs (``UserInputError`` naming the
command's flag) and its output folder before any work, writes its figures and CSV files when
given ``out``, and returns a dataclass with typed, documented fields (``<Name>Result``). Every
result serialises one way (``_result.Result``: ``safe_files.to_jsonable`` of its fields, NaN as
null): what a command prints and what ``reproduce`` writes to ``OUT/sections/``. The
``ballchain`` subcommands (``ballchain/commands/``) only parse flags, call ``run`` and print;
``ballchain reproduce`` calls the experiments directly. Each module loads on first use:
``ballchain.experiments.alignment.run(...)`` works after ``import ballchain``.

================  ============================================  =======================================
subcommand        experiment module                             result
================  ============================================  =======================================
``alignment``     ``alignment``                                 ``AlignmentResult``
``statics``       ``statics_shape``                             ``StaticsShapeResult``
``sizing``        ``sizing_check``                              ``SizingCheckResult``
``field-models``  ``field_models``                              ``FieldModelsResult``
``workspace``     ``workspace``                                 ``WorkspaceResult``
``validation``    ``model_validation``                          ``ValidationResult``
``forces``        ``forces`` (simulation: ``forces_dynamics``)  ``ForcesResult`` (``PinForceResult``)
``plan``          ``planner``                                   ``PlanResult``
``teleop``        ``teleop`` (``run``, ``run_seeds``)           ``TeleopResult``, ``TeleopSeedsResult``
``simulate``      ``simulation``                                ``SimulationResult``
``reconfigure``   ``reconfiguration``                           ``ReconfigurationStudyResult``
``wheels``        ``wheels``                                    ``WheelsResult``
``ablation``      ``ablation``                                  ``AblationResult``
``clinical``      ``clinical``, ``table1_effects``              ``ClinicalResult``, ``EffectsResult``
``bench``         ``statics_bench``                             ``StaticsBenchResult``
(notebook)        ``hall_inversion``                            ``HallInversionResult``
(notebook)        ``lesion_fem_check``                          ``FemCheckResult``
================  ============================================  =======================================
"""

import importlib as _importlib
import pkgutil as _pkgutil


def _modules() -> list[str]:
    return [m.name for m in _pkgutil.iter_modules(__path__) if not m.name.startswith("_")]


def __getattr__(name: str):
    """An experiment module, imported on first use (PEP 562)."""
    if name in _modules():
        return _importlib.import_module(f"{__name__}.{name}")
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_modules()))
