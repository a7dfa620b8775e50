"""The paper's experiments in simulation, each a ``run(...)`` returning plain data.

One module per experiment; its ``run`` checks its inputs (``UserInputError`` naming the
command's flag) and its output folder before any work, and writes its figures and CSV files
when given ``out``. The ``ballchain`` subcommands (``ballchain/commands/``) only parse flags,
call ``run`` and print; ``ballchain reproduce`` calls the experiments directly.

=====================  ======================================================
subcommand             experiment module
=====================  ======================================================
``alignment``          ``alignment``
``statics``            ``statics_shape``
``sizing``             ``sizing_check``
``field-models``       ``field_models``
``workspace``          ``workspace``
``validation``         ``model_validation``
``forces``             ``forces`` (its simulation: ``forces_dynamics``)
``plan``               ``planner``
``teleop``             ``teleop``
``simulate``           ``simulation``
``reconfigure``        ``reconfiguration``
``wheels``             ``wheels``
=====================  ======================================================
"""
