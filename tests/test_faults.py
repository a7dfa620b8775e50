"""Faults: a NaN stops a simulation at once, naming where and when; an interrupted
``reproduce`` leaves no half-written file and ``--resume`` finishes it; statics never reports NaN
as converged; the operator's runs are deterministic across processes.
"""

from __future__ import annotations

import json
import os
import signal
import struct
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import BasicVector, DiagramBuilder, LeafSystem

from ballchain.infrastructure.errors import NonFiniteSignal

HANG_GUARD_S = 60.0  # a NaN that stalls the integrator runs forever; the answer takes milliseconds


class GoesNaN(LeafSystem):
    """A vector source: ``value`` until ``t_nan``, NaN from then on."""

    def __init__(self, size: int, value: float, t_nan: float):
        super().__init__()
        self._value, self._t = value, t_nan
        self.DeclareVectorOutputPort("y", BasicVector(size), self._calc)

    def _calc(self, context, output):
        x = self._value if context.get_time() < self._t else np.nan
        output.SetFromVector(np.full(output.size(), x))


def _systems():
    from ballchain.systems.feeder import Feeder
    from ballchain.systems.omni_wheel_drive import OmniWheelDrive
    from ballchain.systems.rotating_magnet_unit import RotatingMagnetUnit

    return {
        # continuous state, error-controlled integrator: the case that used to retry forever
        "magnet": (RotatingMagnetUnit, "omega_wheels", 0.5, "right_unit.magnet"),
        "feeder": (Feeder, "v_insert_cmd", 0.005, "feeder"),  # discrete (stepper), 2 ms period
        "drive": (OmniWheelDrive, "omega_desired_W", 0.2, "right_unit.drive"),  # discrete, 5 ms
    }


@pytest.mark.parametrize("which", ["magnet", "feeder", "drive"])
def test_nan_input_stops_an_integrating_system_at_once_naming_system_port_and_time(which):
    make, port, value, name = _systems()[which]
    builder = DiagramBuilder()
    system = builder.AddSystem(make())
    source = builder.AddSystem(GoesNaN(system.GetInputPort(port).size(), value, t_nan=0.1))
    builder.Connect(source.get_output_port(), system.GetInputPort(port))
    simulator = Simulator(builder.Build())
    start = time.monotonic()
    with pytest.raises(NonFiniteSignal) as err:
        simulator.AdvanceTo(10.0)
    assert time.monotonic() - start < HANG_GUARD_S
    message = str(err.value)
    assert name in message and f"'{port}'" in message and "nan" in message
    t = float(message.split("at t = ")[1].split(" s")[0])
    # The first evaluation after the NaN: a period later (discrete) or one integrator step (the
    # error-controlled integrator's steps are long while the input is constant).
    assert 0.1 <= t <= 0.2
    assert simulator.get_context().get_time() <= t + 1e-4  # stopped there (the message rounds t)


def test_wrench_system_names_the_port_the_magnet_and_the_time():
    from ballchain.drake_models.params import BallChain, CylinderMagnet
    from ballchain.systems.chain_plant import ChainPlantConfig, add_chain_plant
    from ballchain.systems.magnetic_wrench import MagneticWrenchSystem

    builder = DiagramBuilder()
    cp = add_chain_plant(builder, ChainPlantConfig(chain=BallChain(n_balls=3), heart=None, sheath=None))
    wrench = MagneticWrenchSystem(BallChain(n_balls=3), cp.ball_body_indices,
                                  port_magnets=[CylinderMagnet(), CylinderMagnet()])
    wrench.set_name("magnetic_wrench")
    builder.AddSystem(wrench)
    builder.Connect(cp.plant.get_body_poses_output_port(), wrench.get_body_poses_input_port())
    diagram = builder.Build()
    context = diagram.CreateDefaultContext()
    context.SetTime(0.25)
    wc = wrench.GetMyContextFromRoot(context)
    good = [0.2, 0.0, 0.0, 0.0, 0.0, 1.0]
    for bad, what in (([0.2, 0.0, 0.0, np.nan, 0.0, 1.0], "dipole direction"),
                      ([np.nan, 0.0, 0.0, 0.0, 0.0, 1.0], "centre p_WM"),
                      ([0.2, 0.0, 0.0, 0.0, 0.0, 0.0], "dipole direction is zero")):
        wrench.get_magnet_states_input_port().FixValue(wc, np.array(good + bad))
        with pytest.raises(NonFiniteSignal, match="magnetic_wrench") as err:
            wrench.get_spatial_forces_output_port().Eval(wc)
        message = str(err.value)
        assert "'magnet_states'" in message and "magnet 2 of 2" in message and what in message
        assert "t = 0.25 s" in message


def test_watchdog_names_the_ball_whose_state_is_not_finite():
    from ballchain.systems.chain_scenario import load_scenario
    from ballchain.systems.chain_simulation import ChainMonitor, MakeStation

    cd = MakeStation(load_scenario("free_space_uniform_90deg", "{n_balls: 4}"))
    context = cd.diagram.CreateDefaultContext()
    plant = cd.chain.plant
    pc = plant.GetMyContextFromRoot(context)
    body = cd.chain.ball_bodies[2]
    X = plant.GetFreeBodyPose(pc, body)
    X.set_translation([np.nan, 0.0, 0.0])
    plant.SetFreeBodyPose(pc, body, X)
    message = ChainMonitor(cd).check(pc)
    assert "NaN or inf" in message and "ball 3 (position)" in message

def test_an_engine_update_to_a_non_finite_state_stops_the_run_at_that_update():
    """The watchdog reads the engine's state only at its checks (the chain moves only at the
    engine's updates): an update that leaves a NaN is reported by the engine, and the run stops
    at the end of that very step, even between two checks."""
    from ballchain.systems.chain_scenario import load_scenario
    from ballchain.systems.chain_simulation import ChainMonitor, MakeStation

    cd = MakeStation(load_scenario("heart_left_quasi_static", "{engine: statics, duration: 0.3}"))
    engine = cd.chain.engine_system
    walk = engine._walk
    poisoned_at = []

    def poisoned(t, *args, **kwargs):
        p, m, result, motion = walk(t, *args, **kwargs)
        if t >= 0.1 - 1e-9:
            poisoned_at.append(t)
            p = p.copy()
            p[4, 1] = np.nan
        return p, m, result, motion

    engine._walk = poisoned
    simulator = Simulator(cd.diagram)
    monitor = ChainMonitor(cd)
    simulator.set_monitor(monitor)
    simulator.Initialize()
    monitor._next_check = 1.0  # no periodic check before the end: only the engine's report stops it
    with pytest.raises(RuntimeError, match=r"NaN or inf in the state at t = (\d\.\d+) s: ball 5 .position.") as err:
        simulator.AdvanceTo(0.3)
    # Drake applies the update made at t during the step from t: the monitor, called at that
    # step's end (the engine's next update time, the only events), stops the run there.
    stop = poisoned_at[0] + engine.period
    assert len(poisoned_at) == 1 and simulator.get_context().get_time() == pytest.approx(stop)
    assert f"t = {stop:.4f} s" in str(err.value)



def test_nan_joystick_in_the_station_stops_at_once_naming_the_unit():
    """The old hang on a NaN stick axis: now the first derivative evaluation refuses it."""
    from ballchain.systems.chain_scenario import load_scenario
    from ballchain.systems.chain_simulation import MakeStation

    scenario = load_scenario("teleop_right_unit", "{heart: false, sheath: false, n_balls: 4, duration: 0.05, "
                             "insertion: {initial: 0.0, final: 0.0}, "
                             "units: [{name: right_unit, anchor: puncture, distance: 0.1}]}")
    scenario.units[0].joystick_source = "external"
    scenario.units[0].joystick = []
    cd = MakeStation(scenario.validate())
    simulator = Simulator(cd.diagram)
    port = cd.diagram.GetInputPort("right_unit.joystick")
    port.FixValue(simulator.get_mutable_context(), np.array([np.nan, 0.0, 0.0]))
    start = time.monotonic()
    with pytest.raises(NonFiniteSignal, match=r"right_unit\.\w+: input port '\w+' is not finite at t = 0"):
        simulator.AdvanceTo(0.05)
    assert time.monotonic() - start < HANG_GUARD_S


@pytest.mark.parametrize("method", ["newton", "snopt"])
def test_statics_on_a_nan_field_is_not_converged_and_says_why(method):
    from ballchain.drake_models.params import BallChain
    from ballchain.optimization.statics import ChainStatics

    class NaNField:
        def field_and_gradient(self, p):
            B = np.zeros((len(p), 3))
            B[2] = np.nan
            return B, np.zeros((len(p), 3, 3))

    result = ChainStatics(BallChain(n_balls=5), method=method).solve(NaNField())
    assert not result.converged
    assert "not finite" in result.reason and "ball 3" in result.reason


# ------------------------------------------------------------------ reproduce: nothing lost

def _fake_experiments(calls: dict, fail_at: str | None = None):
    from ballchain.infrastructure.safe_files import atomic_write_text
    from ballchain.report import Section

    def make(name):
        def section(out: Path, quick: bool):
            calls[name] = calls.get(name, 0) + 1
            if name == fail_at:
                raise KeyboardInterrupt  # Ctrl-C in the middle of this section
            atomic_write_text(out / f"{name}.txt", f"{name} quick={quick}\n")
            return Section(f"Section {name}").text(f"{name} done").table(["x"], [[1.5], [float("nan")]]), {"n": name}
        return section

    from ballchain.reproduce import ReportSection

    return [ReportSection(name, make(name)) for name in ("one", "two", "three")]


def test_resume_reuses_finished_sections_and_checks_them_by_content(tmp_path, monkeypatch):
    from ballchain import reproduce

    calls: dict = {}
    monkeypatch.setattr(reproduce.registry, "SECTIONS", _fake_experiments(calls, fail_at="two"))
    with pytest.raises(KeyboardInterrupt):
        reproduce.run(out=tmp_path, quick=True)
    report = (tmp_path / "report.md").read_text()
    assert "Section one" in report and "Not finished" in report and "two, three" in report
    assert json.loads((tmp_path / "sections" / "one.json").read_text()) == {"n": "one"}

    monkeypatch.setattr(reproduce.registry, "SECTIONS", _fake_experiments(calls))
    data = reproduce.run(out=tmp_path, quick=True, resume=True)
    assert data["reused"] == ["one"] and calls == {"one": 1, "two": 2, "three": 1}
    report = (tmp_path / "report.md").read_text()
    assert all(f"Section {n}" in report for n in ("one", "two", "three")) and "Not finished" not in report

    # Checked by content: a changed file, other inputs (--quick) or other code run it again.
    (tmp_path / "one.txt").write_text("edited\n")
    assert reproduce.run(out=tmp_path, quick=True, resume=True)["reused"] == ["two", "three"]
    assert reproduce.run(out=tmp_path, quick=False, resume=True)["reused"] == []
    monkeypatch.setattr(reproduce.runner, "code_version", lambda: "another version")
    assert reproduce.run(out=tmp_path, quick=False, resume=True)["reused"] == []
    assert calls == {"one": 4, "two": 4, "three": 3}


def _check_complete(out: Path, temporary_allowed: bool = False) -> list[str]:
    """Every result file under out is whole (by its format); returns the relative paths checked.

    A SIGKILL during a write leaves the writer's temporary file (``.<name>.<random>.partial``),
    never a truncated result: those are allowed right after a kill (``--resume`` removes them)."""
    checked = []
    for path in sorted(p for p in out.rglob("*") if p.is_file()):
        rel = path.relative_to(out).as_posix()
        if path.name.endswith(".partial"):
            assert temporary_allowed, f"temporary file left behind: {rel}"
            continue
        data = path.read_bytes()
        if path.suffix == ".json":
            json.loads(data)
        elif path.suffix == ".png":
            assert data.startswith(b"\x89PNG\r\n\x1a\n") and data[-12:-4] == struct.pack(">I", 0) + b"IEND", rel
        elif path.suffix == ".csv":
            rows = data.decode().splitlines()
            assert len(rows) >= 2 and len({r.count(",") for r in rows if '"' not in r}) == 1, rel
        elif path.suffix == ".html":
            assert data.rstrip().endswith(b"</html>"), rel
        elif path.suffix == ".md":
            assert b"## Run time" in data, rel
        checked.append(rel)
    return checked


# The kill comes after the second section; the last one (the lesion model, several seconds in quick
# mode) keeps the run busy until then, so the signal never lands in a run that is already exiting.
SECTIONS = ["alignment", "sizing", "field models", "model validation", "ablation"]


def _reproduce(out: Path, *extra: str) -> list[str]:
    return [sys.executable, "-m", "ballchain", "reproduce", "--quick", "--out", str(out), "--sections", *SECTIONS,
            *extra]


def _wait_for(path: Path, proc, timeout: float = 300.0) -> None:
    end = time.monotonic() + timeout
    while not path.exists():
        assert proc.poll() is None, proc.communicate()
        assert time.monotonic() < end, f"{path} did not appear"
        time.sleep(0.05)


@pytest.fixture(scope="module")
def warm_reproduce(tmp_path_factory):
    """The same run once to the end first, so that the killed runs find the kernels in numba's
    cache and their sections take their usual time (a fresh clone's first run compiles them)."""
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    subprocess.run(_reproduce(tmp_path_factory.mktemp("warm-up")), capture_output=True, env=env, check=True,
                   timeout=600)


@pytest.mark.slow
@pytest.mark.parametrize("how", ["SIGKILL", "SIGINT", "SIGTERM", "SIGHUP"])
def test_killed_reproduce_leaves_whole_files_and_resume_finishes_it(tmp_path, how, warm_reproduce):
    """Kill ``reproduce --quick`` after its second section (SIGKILL: no clean-up at all; SIGINT:
    Ctrl-C; SIGTERM: ``kill``, a time limit; SIGHUP: the terminal closed), check that every
    file left is whole, then ``--resume`` reuses the finished sections and runs the rest."""
    out = tmp_path / "results"
    # A crash prints its stacks (a SIGSEGV under SIGTERM was seen once in CI, December 4th).
    env = {**os.environ, "PYTHONUNBUFFERED": "1", "PYTHONFAULTHANDLER": "1"}
    proc = subprocess.Popen(_reproduce(out), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    _wait_for(out / ".reproduce" / "sizing.json", proc)
    signum = getattr(signal, how)
    proc.send_signal(signum)
    _, err = proc.communicate(timeout=120)
    if how != "SIGKILL":  # stopped like Ctrl-C: the finished sections kept, status 128 + the signal
        assert proc.returncode == 128 + signum, err[-3000:]
        assert "--resume" in err and "interrupted" in err
    else:
        assert proc.returncode == -signal.SIGKILL
    finished = {p.stem for p in (out / ".reproduce").glob("*.json")}
    assert {"alignment", "sizing"} <= finished and len(finished) < len(SECTIONS)
    for rel in _check_complete(out, temporary_allowed=(how == "SIGKILL")):
        assert not rel.startswith("validation/")  # not started when killed
    proc = subprocess.run(_reproduce(out, "--resume", "--json"), capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr
    data = json.loads(proc.stdout)
    assert set(data["reused"]) >= {"alignment", "sizing"}
    assert set(data["experiments"]) == set(SECTIONS)
    assert not (set(data["reused"]) & {"model validation"})
    assert "validation/validation.csv" in _check_complete(out)
    report = (out / "report.md").read_text()
    assert "Not finished" not in report and "Model validation" in report


@pytest.mark.slow
def test_teleoperation_runs_are_deterministic_across_processes():
    """The notebook's teleoperation runs (the quasi-static engine) give the same rows whatever the
    process's hash seed and BLAS thread count (its one failure in a full run was time, not chaos:
    tests/test_notebooks.py)."""
    code = ("import json; from ballchain.experiments import teleop\n"
            "r = teleop.run(task='right', mapping='world', targets=1, progress=False)\n"
            "print(json.dumps(r.rows))")
    rows = []
    for seed, threads in (("1", "1"), ("2", "2")):
        env = {**os.environ, "PYTHONHASHSEED": seed, "OPENBLAS_NUM_THREADS": threads, "OMP_NUM_THREADS": threads}
        proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=900, env=env)
        assert proc.returncode == 0, proc.stderr
        rows.append(json.loads(proc.stdout.splitlines()[-1]))
    assert rows[0] == rows[1] and rows[0][0]["touched"]


@pytest.mark.slow
def test_ctrl_c_in_simulate_keeps_the_replay_recorded_so_far(tmp_path):
    """Ctrl-C during ``simulate --html``: exit 130, one note, and a whole replay up to then."""
    html, log = tmp_path / "replay.html", tmp_path / "stderr.txt"
    argv = [sys.executable, "-m", "ballchain", "simulate", "--scenario", "free_space_uniform_90deg",
            "--duration", "600", "--html", str(html)]
    with log.open("w") as err:
        proc = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=err, text=True)
        end = time.monotonic() + 300
        while "sim s" not in log.read_text():  # the progress bar: the simulation is running
            assert proc.poll() is None and time.monotonic() < end, log.read_text()
            time.sleep(0.1)
        time.sleep(1.0)
        proc.send_signal(signal.SIGINT)
        proc.wait(timeout=120)
    assert proc.returncode == 130
    text = log.read_text()
    assert "interrupted at t = " in text and "ballchain simulate: interrupted" in text
    assert html.read_bytes().rstrip().endswith(b"</html>")
    assert not list(tmp_path.glob("*.partial"))


def test_an_interrupt_wrapped_by_a_compiled_call_is_still_an_interrupt():
    """Ctrl-C landing inside a numba dispatcher comes back as a SystemError whose context is the
    KeyboardInterrupt: it is treated as Ctrl-C (exit 130), not as a bug."""
    from ballchain.infrastructure.errors import caused_by_interrupt

    try:
        try:
            raise KeyboardInterrupt
        except KeyboardInterrupt:
            raise SystemError("CPUDispatcher(...) returned a result with an exception set")
    except SystemError as err:
        wrapped = err
    assert caused_by_interrupt(wrapped) and caused_by_interrupt(KeyboardInterrupt())
    assert not caused_by_interrupt(SystemError("a bug")) and not caused_by_interrupt(ValueError("bad"))
