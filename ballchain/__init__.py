"""Magnetic ball-chain catheter simulation on Drake.

The public API is what ``ballchain`` exports (``__all__``): a first script needs one import::

    import ballchain as bc

    station = bc.MakeStation(bc.load_scenario("heart_left_quasi_static"))
    outcome = bc.run_station(station, duration=1.0)
    print(outcome.tip_position)  # (3,) [m]
    result = bc.ChainStatics(bc.BallChain(n_balls=16)).solve(bc.UniformField([0.0, 0.023, 0.0]))
    print(result.tip_position)  # (3,) [m]

The exported names, by job:

- scenarios: ``ChainScenario``, ``load_scenario``, ``scenario_names``, ``scenario_descriptions``,
  ``parse_overrides``, ``apply_overrides``;
- the station and its run: ``MakeStation``, ``Station``, ``DeviceModel`` (the interface every
  device implements; ``ChainModel``, the ball chain's) and ``register_device_model`` (a new device), ``MagnetUnitConfig``,
  ``StationOptions`` and ``make_actuation_station`` (the units and the feeder alone),
  ``StationPorts`` (what an ``add_systems`` hook connects to), ``run_station``, ``RunOutcome``,
  ``StationRunner``, ``ChainMonitor`` (and ``near_ostium_rim``, the rule by which it tolerates a
  ball sinking at a vein's rim), ``run_simulation``, ``SimulationMetrics``, ``SimulationFailure``,
  ``add_field_following_operator`` (an operator steering the tip to a point: an ``add_systems``
  hook);
- statics: ``ChainStatics``, ``StaticsResult``, ``StaticsError``, ``BallChain``, ``Sleeve``,
  ``UniformField``, ``MagnetSource``, ``FieldSources``, ``FieldSource`` (the protocol a new
  source implements), ``CylinderMagnet``, ``SphereMagnet``;
- anatomy: ``LeftAtrium`` (the procedural atrium), ``UserAtrium`` (a segmented one), ``Atrium``
  (the protocol a new atrium implements), ``load_anatomy`` (an anatomy file);
- the paper's experiments: ``experiments`` (``ballchain.experiments.<name>.run``);
- statistics over seeds: ``intervals`` (``interval``, ``paired_interval``,
  ``difference_interval``, ``proportion_interval``, ``agrees``, ``side_agrees``: a result's 95 %
  bootstrap interval and the verdict rule of docs/guide/trials.md);
- sweeps: ``SweepSpec``, ``load_spec``, ``Executor``, ``run_sweep``;
- errors: ``UserInputError`` (bad input, naming the field and what is allowed).

The names load when first used (a module ``__getattr__``), so ``import ballchain`` does not
import Drake. Every other name, in ``ballchain`` or its sub-packages, is private by convention:
it may change without notice. The layers live in sub-packages: ``ballchain.drake_models``
(physics and models), ``ballchain.optimization`` (MathematicalProgram problems),
``ballchain.systems`` (LeafSystems and diagrams), all above ``ballchain.infrastructure`` (errors,
safe files, YAML, numba's cache); ``ballchain.cli`` is the ``ballchain`` command.
"""

import importlib as _importlib

__version__ = "0.1.0"

# exported name -> the module that defines it (its one home)
_EXPORTS: dict[str, str] = {
    "ChainScenario": "ballchain.systems.chain_scenario",
    "load_scenario": "ballchain.systems.chain_scenario",
    "scenario_names": "ballchain.systems.chain_scenario",
    "scenario_descriptions": "ballchain.systems.chain_scenario",
    "parse_overrides": "ballchain.systems.chain_scenario",
    "apply_overrides": "ballchain.systems.chain_scenario",
    "MakeStation": "ballchain.systems.station",
    "Station": "ballchain.systems.station",
    "DeviceModel": "ballchain.systems.device_model",
    "ChainModel": "ballchain.systems.chain_model",
    "register_device_model": "ballchain.systems.device_model",
    "MagnetUnitConfig": "ballchain.systems.unit_config",
    "StationOptions": "ballchain.systems.actuation_station",
    "make_actuation_station": "ballchain.systems.actuation_station",
    "StationPorts": "ballchain.systems.station",
    "run_station": "ballchain.systems.chain_simulation",
    "RunOutcome": "ballchain.systems.chain_simulation",
    "StationRunner": "ballchain.systems.chain_simulation",
    "ChainMonitor": "ballchain.systems.chain_simulation",
    "near_ostium_rim": "ballchain.systems.chain_simulation",
    "run_simulation": "ballchain.systems.chain_simulation",
    "SimulationFailure": "ballchain.systems.chain_simulation",
    "SimulationMetrics": "ballchain.systems.chain_simulation",
    "add_field_following_operator": "ballchain.systems.field_following_operator",
    "ChainStatics": "ballchain.optimization.statics",
    "StaticsResult": "ballchain.optimization.statics",
    "StaticsError": "ballchain.optimization.statics",
    "BallChain": "ballchain.drake_models.params",
    "Sleeve": "ballchain.drake_models.params",
    "CylinderMagnet": "ballchain.drake_models.params",
    "SphereMagnet": "ballchain.drake_models.params",
    "UniformField": "ballchain.drake_models.field_sources",
    "MagnetSource": "ballchain.drake_models.field_sources",
    "FieldSources": "ballchain.drake_models.field_sources",
    "FieldSource": "ballchain.drake_models.field_sources",
    "LeftAtrium": "ballchain.drake_models.heart",
    "UserAtrium": "ballchain.drake_models.atrium_mesh",
    "Atrium": "ballchain.drake_models.atrium",
    "load_anatomy": "ballchain.drake_models.anatomy",
    "UserInputError": "ballchain.infrastructure.errors",
    "SweepSpec": "ballchain.sweep",
    "load_spec": "ballchain.sweep",
    "Executor": "ballchain.sweep",
    "run_sweep": "ballchain.sweep",
}
_SUBPACKAGES = ("experiments", "intervals")  # sub-packages and public modules, sorted

__all__ = ["__version__", *_EXPORTS, *_SUBPACKAGES]


def __getattr__(name: str):
    """Load an exported name on first use (PEP 562) and keep it in the module's namespace."""
    if name in _EXPORTS:
        value = getattr(_importlib.import_module(_EXPORTS[name]), name)
    elif name in _SUBPACKAGES:
        value = _importlib.import_module(f"{__name__}.{name}")
    else:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
