"""CPU time of each actuation unit's callbacks, one at a time, on a running station's context.

The station (``--scenario``, on the quasi-static engine) is advanced to ``--at`` seconds (the
magnet turning in ``teleop_right_unit``), then each callback of the first unit (and the feeder and
the watchdog) is called on its own context ``--number`` times: the composed Python systems'
(``unit_systems: python``) and the compiled ``ActuationUnit``'s (a second station advanced alike), the best of 5 repeats (CPU time,
``time.process_time``). A discrete update writes into a scratch ``DiscreteValues``. Port values
the callback evaluates are cached by Drake after the first call, as within one simulator step.
"Hall sample, turned" forgets the sensor's remembered field first, as when the magnet has turned
since the last sample.

    python benchmarks/unit_callbacks.py
    python benchmarks/unit_callbacks.py --scenario teleop_two_units --at 0.6

Prints one line per callback: microseconds per call. A loaded machine inflates every line alike;
compare two versions in the same conditions.
"""

from __future__ import annotations

import argparse
import time
import timeit


def _advanced(scenario: str, at: float, unit_systems: str):
    from pydrake.systems.analysis import Simulator

    from ballchain.systems.chain_scenario import load_scenario
    from ballchain.systems.chain_simulation import ChainMonitor, MakeStation

    station = MakeStation(load_scenario(scenario, f"{{engine: statics, mode: quasi-static, unit_systems: {unit_systems}}}"))
    simulator = Simulator(station.diagram)
    monitor = ChainMonitor(station)
    simulator.set_monitor(monitor)
    simulator.Initialize()
    simulator.AdvanceTo(at)
    return station, simulator, monitor


def run(scenario: str = "teleop_right_unit", at: float = 0.3031, number: int = 2000) -> dict[str, float]:
    station, simulator, monitor = _advanced(scenario, at, "python")  # the composed units' callbacks
    compiled, compiled_simulator, _ = _advanced(scenario, at, "compiled")
    root = simulator.get_context()
    unit = next(iter(station.units.values()))

    def own(system):
        return system.GetMyContextFromRoot(root)

    def update(system, method):
        context, scratch = own(system), system.AllocateDiscreteVariables()
        return lambda: method(context, scratch)

    def output(system, port, method):
        context, value = own(system), port.Allocate()
        target = value if port.get_data_type().name == "kAbstractValued" else value.get_mutable_value()
        return lambda: method(context, target)

    sensor = unit.sensor
    sensor_update = update(sensor, sensor._sample)

    def hall_turned():
        sensor._last_fields[0] = None
        sensor_update()

    mode_switch = station.diagram.GetSubsystemByName(f"{unit.config.name}.mode_switch")
    cases = {
        "Hall sample, turned": hall_turned,
        "Hall sample, same orientation": sensor_update,
        "magnet update": update(unit.magnet, unit.magnet._update),
        "magnet pose output (X_WM)": output(unit.magnet, unit.magnet.GetOutputPort("X_WM"), unit.magnet._calc_X_WM),
        "drive update": update(unit.drive, unit.drive._update),
        "mapper output": output(unit.teleoperation, unit.teleoperation.GetOutputPort("omega_desired_W"),
                                unit.teleoperation._calc),
        "mode switch output": output(mode_switch, mode_switch.GetOutputPort("omega_desired_W"), mode_switch._calc),
        "controller latch": update(unit.controller, unit.controller._update_done),
        "watchdog (a step between checks)": lambda: monitor(root),
    }
    # The same unit as one ActuationUnit: its update at a Hall sample's time (every system's work
    # of the composed unit at that time) and between samples, and its pose output.
    fused = next(iter(compiled.units.values())).magnet
    compiled_root = compiled_simulator.get_context()
    fused_context = fused.GetMyContextFromRoot(compiled_root)
    period = fused.update_period
    samples = round((1.0 / fused.sensor_spec.sample_rate_hz) / period)
    sample_time = round(at / (samples * period)) * samples * period

    def fused_update(t):
        scratch = fused.AllocateDiscreteVariables()

        def call():
            if compiled_root.get_time() != t:  # once: then the inputs stay cached, as above
                compiled_root.SetTime(t)
            fused._update(fused_context, scratch)
        return call

    pose = fused.GetOutputPort("X_WM").Allocate()
    cases["compiled unit update, Hall sample"] = fused_update(sample_time)
    cases["compiled unit update, between samples"] = fused_update(sample_time + period)
    cases["compiled unit pose output (X_WM)"] = lambda: fused._calc_X_WM(fused_context, pose)
    if station.feeder is not None:
        cases["feeder update"] = update(station.feeder, station.feeder._update)
    out = {}
    for name, call in cases.items():
        best = min(timeit.repeat(call, number=number, repeat=5, timer=time.process_time)) / number
        out[name] = round(best * 1e6, 2)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scenario", default="teleop_right_unit", help="a scenario with actuation units")
    parser.add_argument("--at", type=float, default=0.3031, help="simulated time of the context [s]")
    parser.add_argument("--number", type=int, default=2000, help="calls per repeat")
    args = parser.parse_args()
    for name, us in run(args.scenario, args.at, args.number).items():
        print(f"{name:40s} {us:8.2f} us")


if __name__ == "__main__":
    main()
