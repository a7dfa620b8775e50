"""The Drake systems and diagrams: the station builder, its chain models, units and run loop.

``station`` (``MakeStation``, ``Station``), ``chain_scenario`` (the scenario schema and its
loading), ``chain_simulation`` (``run_station``, the watchdog), the two chain engines
(``chain_plant``: the MultibodyPlant; ``quasi_static_engine``: the statics solved every
period), the actuation units, feeder, sensors, operators and Meshcat views. The public names are
re-exported by ``ballchain`` (``ballchain.__all__``); the rest is private by convention.
"""
