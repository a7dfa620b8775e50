"""The procedure's runs (``procedure.run``): the station with the autonomous navigator
(``_simulate``) or the simulated operator (``_simulate_operator``), their ``add_systems`` hooks,
the per-target rows and the summary, and what follows a run (``_finisher``).
"""

from __future__ import annotations

import numpy as np

from ballchain.drake_models.localisation import LocalisationParams
from ballchain.drake_models.params import gram_force
from ballchain.experiments.procedure_result import ProcedureResult, with_lesions


def _estimator(ports, chain, n_balls: int):
    """The navigator's force model from what the station's hook sees (atrium, units)."""
    from ballchain.drake_models.field_sources import rotation_with_z_along
    from ballchain.systems.tip_force_estimator import TipForceEstimator

    heart, units = ports.heart, list(ports.units.values())
    R_WS = rotation_with_z_along(heart.sheath_axis_H)[:, [2, 0, 1]]
    magnets = [(h.config.magnet, np.asarray(h.config.p_WM, float)) for h in units]
    return TipForceEstimator(chain, heart.p_HE, R_WS, magnets, units[0].config.model, n_balls)


def _add_sheath_tracker(builder, ports, localisation: LocalisationParams, seed: int):
    """A localisation sensor on the sheath (respiratory compensation): the tracked sheath's
    displacement from its rest pose, i.e. the heart's (the quasi-static engine's
    ``anatomy_offsets``; zero on a still wall), with the tip sensor's noise, rate and latency and
    a noise stream of its own. Returns its ``p_WT_measured`` output."""
    from pydrake.systems.primitives import ConstantVectorSource, MatrixGain

    from ballchain.systems.localisation_sensor import LocalisationSensor

    own_seed = int(np.random.SeedSequence((seed, 1)).generate_state(1)[0])  # not the tip sensor's stream
    sensor = builder.AddSystem(LocalisationSensor(1, localisation, own_seed, name="sheath_localisation"))
    offsets = ports.device.get_anatomy_offsets_output_port()
    if offsets is None:  # a still wall: the sheath stays at rest
        source = builder.AddSystem(ConstantVectorSource(np.zeros(3))).get_output_port()
    else:  # the first three: the heart's (and the sheath's) offset
        source = builder.AddSystem(MatrixGain(np.hstack([np.eye(3), np.zeros((3, 3))]))).get_output_port()
        builder.Connect(offsets, source.get_system().get_input_port())
    builder.Connect(source, sensor.get_ball_positions_input_port())
    return sensor.GetOutputPort("p_WT_measured")


def _add_auto(handles: dict, plans: list, localisation: LocalisationParams, params, seed: int,
              track_sheath: bool = False, bias=None):
    """The ``add_systems`` hook of the autonomous run: sensor, navigator, loggers (and with
    ``track_sheath`` the sheath's sensor, ``_add_sheath_tracker``); ``bias``: the world's
    tracker bias (3,) [m] on the tip's readings (``world_apply.biased_reading``), or None."""
    from pydrake.systems.primitives import LogVectorOutput

    from ballchain.drake_models.params import BallChain
    from ballchain.systems.autonomous_navigator import AutonomousNavigator
    from ballchain.systems.localisation_sensor import LocalisationSensor

    def add(builder, ports):
        cp = ports.chain
        n = cp.config.chain.n_balls
        sensor = builder.AddSystem(LocalisationSensor(n, localisation, seed))
        builder.Connect(cp.get_ball_positions_output_port(), sensor.get_ball_positions_input_port())
        measured = sensor.GetOutputPort("p_WT_measured")
        if bias is not None:  # the world's tracker bias, unknown to the navigator
            from ballchain.systems.world_apply import biased_reading

            measured = biased_reading(builder, measured, bias)
        units = list(ports.joystick_inputs)
        nav = builder.AddSystem(AutonomousNavigator(units, plans, _estimator(ports, BallChain(), n), params,
                                                    tracks_sheath=track_sheath))
        builder.Connect(measured, nav.GetInputPort("p_WT_measured"))
        if track_sheath:
            builder.Connect(_add_sheath_tracker(builder, ports, localisation, seed),
                            nav.GetInputPort("sheath_offset_measured"))
        for u in units:
            builder.Connect(ports.units[u].magnet.GetOutputPort("m_W"), nav.GetInputPort(f"m_W_{u}"))
            builder.Connect(nav.GetOutputPort(f"joystick_{u}"), ports.joystick_inputs[u])
        feeder = ports.feeder_command_input.get_system()
        builder.Connect(feeder.GetOutputPort("inserted_length"), nav.GetInputPort("inserted_length"))
        builder.Connect(nav.GetOutputPort("v_insert_cmd"), ports.feeder_command_input)
        period = params.period
        handles["logs"] = [LogVectorOutput(port, builder, period) for port in (
            cp.get_tip_wall_force_output_port(), cp.get_ball_positions_output_port(),
            nav.GetOutputPort("force_estimate"), measured)]
        handles["navigator"] = nav
        return {"navigator": nav, "localisation": sensor}

    return add


def _dwell_row(record, logs, context, plan, window_N, ball_radius: float, look_period: float) -> dict:
    """One target's row from the navigator's record and the run's logs (sampled every navigator
    period; ``look_period``: how often it looked in the dwell, each look standing for the samples
    since the one before)."""
    force, balls, estimate, _ = (log.FindLog(context) for log in logs)
    t = force.sample_times()
    row = {"target": record.target, "reached": record.reached, "retries": record.retries, "slips": record.slips,
           "captures": record.captures,
           "plan_force_gf": round(gram_force(plan.force_N), 3), "aim_offset_mm": round(plan.aim_offset * 1e3, 3),
           "time_s": None if record.t_end is None else round(record.t_end - record.t_start, 3),
           "t_touch_s": None if record.t_touch is None else round(record.t_touch, 3), "dwell_s": 0.0,
           "force_true_mean_gf": None, "force_true_min_gf": None, "force_true_max_gf": None,
           "in_window_fraction": None, "estimate_mean_error_gf": None, "estimate_worst_error_gf": None,
           "point": None, "reason": None}
    if not record.reached:
        row["reason"] = "gave up" if record.t_end is not None else "run ended"
        return row
    # The dwell's samples: each look's and those since the one before (on the target; a slip off
    # it and the seek back are not RF time), the estimate held between the looks.
    looks = np.round(np.array([e[0] for e in record.estimates]), 6)
    mask = np.zeros(len(t), bool)
    if looks.size:
        t6 = np.round(t, 6)
        k = np.minimum(np.searchsorted(looks, t6), looks.size - 1)  # the first look at or after each sample
        mask = (t6 <= looks[k]) & (looks[k] - t6 < look_period - 1e-7)
    if not mask.any():
        return row
    f_W = force.data()[:3, mask].T
    true = f_W @ plan.n_W  # the wall's push on the tip, along its outward normal
    est = estimate.data()[0, mask]
    err = est - true
    lo, hi = window_N
    tip = balls.data()[-3:, mask].T
    mean_f = f_W.mean(axis=0)
    n_out = mean_f / np.linalg.norm(mean_f) if np.linalg.norm(mean_f) > 1e-9 else plan.n_W
    row.update(dwell_s=round(record.dwell_time, 3),
               force_true_mean_gf=round(gram_force(float(true.mean())), 3),
               force_true_min_gf=round(gram_force(float(true.min())), 3),
               force_true_max_gf=round(gram_force(float(true.max())), 3),
               in_window_fraction=round(float(np.mean((true >= lo) & (true <= hi))), 4),
               estimate_mean_error_gf=round(gram_force(float(np.mean(err))), 3),
               estimate_worst_error_gf=round(gram_force(float(np.max(np.abs(err)))), 3))
    row["point"] = {"name": record.target, "p_W": (tip.mean(axis=0) - ball_radius * n_out).tolist(),
                    "n_W": n_out.tolist(), "force_N": float(true.mean()), "duration_s": row["dwell_s"]}
    row["_errors"] = err
    row["_in_window"] = (true >= lo) & (true <= hi)
    return row


def _summary(rows: list, run, plan_cpu: float, missing: list) -> dict:
    errors = [r.pop("_errors") for r in rows if "_errors" in r]
    inside = [r.pop("_in_window") for r in rows if "_in_window" in r]
    err = np.concatenate(errors) if errors else np.zeros(0)
    spent = [r["time_s"] for r in rows if r["time_s"] is not None]
    return {"reached": sum(r["reached"] for r in rows), "targets": len(rows),
            "total_time_s": round(float(sum(spent)), 3),
            "in_window_fraction": round(float(np.mean(np.concatenate(inside))), 4) if inside else None,
            "estimate_mean_abs_error_gf": round(gram_force(float(np.mean(np.abs(err)))), 3) if err.size else None,
            "estimate_mean_error_gf": round(gram_force(float(np.mean(err))), 3) if err.size else None,
            "estimate_worst_error_gf": round(gram_force(float(np.max(np.abs(err)))), 3) if err.size else None,
            "not_planned": missing, "sim_time_s": round(run.sim_time, 3), "cpu_time_s": round(run.cpu_time, 2),
            "plan_cpu_time_s": round(plan_cpu, 2), "failure": run.failure}


def _fed_every(scenario, period: float):
    """A copy of the scenario whose feeder steps in batches at the looks, every ``period`` [s],
    of the system that commands it (``teleop.command_period``: the same numbers)."""
    from dataclasses import replace

    from ballchain.experiments import teleop

    scenario = replace(scenario, insertion=replace(scenario.insertion))
    teleop.command_period(scenario, period)
    return scenario


def _check_batches(cd, period: float) -> None:
    """The feeder batches its steps at the looks of the system that commands it, or steps alone
    (a mismatch would apply commands late: a bug, not an input)."""
    batches = None if cd.feeder is None else cd.feeder.command_period
    if batches not in (None, period):
        raise RuntimeError(f"the feeder batches its steps every {batches} s, its commander looks every {period} s")


def _finisher(lesions: bool, ring_order: list[str], html):
    """What follows a run: the rows in ring order, the lesions and the ring (``with_lesions``),
    and their patches drawn into the replay (rewritten with them)."""

    def finish(result: ProcedureResult, cd, meshcat) -> ProcedureResult:
        place = {name: k for k, name in enumerate(ring_order)}  # the rows in ring order (unplanned ones too)
        result.rows.sort(key=lambda row: place.get(row["target"], len(place)))
        if lesions:
            with_lesions(result, ring_order)
        if html is not None and meshcat is not None and result.verdict is not None:
            from ballchain.drake_models.lesion_ring import draw_lesions
            from ballchain.infrastructure.safe_files import atomic_write_text
            from ballchain.systems.chain_simulation import captioned_replay, replay_caption

            draw_lesions(meshcat, result.lesion_objects, result.verdict)
            atomic_write_text(html, captioned_replay(meshcat.StaticHtml(), replay_caption(cd.scenario)))
        return result

    return finish


def _simulate(task, anatomy, scenario, plans, missing, params, localisation, seed, plan_cpu, progress, html,
              overrides, track_sheath: bool = False) -> ProcedureResult:
    """Build the station with the navigator, run it, and tabulate."""
    from ballchain.systems.chain_simulation import (ChainMonitor, MakeStation, after_updates, near_ostium_rim,
                                                    run_station)

    heart = anatomy.atrium()
    handles: dict = {}
    if not plans:  # nothing the model can press: nothing to run
        rows = [{"target": name, "reached": False, "time_s": None, "reason": "no plan"} for name in missing]
        summary = {"reached": 0, "targets": len(rows), "total_time_s": 0.0, "not_planned": missing,
                   "plan_cpu_time_s": round(plan_cpu, 2), "failure": None}
        return ProcedureResult(task=task, navigator="auto", rows=rows, summary=summary,
                               settings=_settings(params, seed, scenario, overrides, 0.0, anatomy, localisation)), None, None
    meshcat = None
    if html is not None:
        from ballchain.systems.chain_simulation import replay_meshcat

        meshcat = replay_meshcat()
    per_target = 15.0 + params.seek_timeout * (params.retries + 1) + params.dwell
    limit = params.start_time + per_target * max(len(plans), 1)
    from ballchain.systems.world_apply import world_draw

    world = world_draw(scenario)
    cd = MakeStation(_fed_every(scenario, params.period), meshcat=meshcat, heart=heart,
                     add_systems=_add_auto(handles, plans, localisation, params, seed, track_sheath,
                                           None if world is None else world.localisation_bias))
    nav = handles["navigator"]
    _check_batches(cd, nav.params.period)
    monitor = ChainMonitor(cd, tolerate_sinking=lambda p: near_ostium_rim(heart, p))
    run = run_station(cd, duration=limit, monitor=monitor,
                      stop=after_updates(lambda c: nav.is_done(nav.GetMyContextFromRoot(c)), nav.params.period),
                      progress=f"procedure {task or anatomy.name}/auto" if progress else None, progress_step=0.5,
                      html=html, meshcat=meshcat)
    records = {r.target: r for r in nav.records(nav.GetMyContextFromRoot(run.context))}
    window = params.force_window
    ball_r = 0.5 * cd.chain.config.chain.ball_diameter
    rows = []
    for plan in plans:
        rec = records.get(plan.name)
        if rec is None:
            rows.append({"target": plan.name, "reached": False, "time_s": None, "reason": "not reached"})
            continue
        rows.append(_dwell_row(rec, handles["logs"], run.context, plan, window, ball_r, nav.params.dwell_period))
    rows += [{"target": name, "reached": False, "time_s": None, "reason": "no plan"} for name in missing]
    summary = _summary(rows, run, plan_cpu, missing)
    settings = {**_settings(params, seed, scenario, overrides, limit, anatomy, localisation),
                "navigator_tracks_sheath": track_sheath, "world": None if world is None else world.to_dict()}
    return ProcedureResult(task=task, navigator="auto", rows=rows, summary=summary, settings=settings,
                           html=None if html is None else str(html)), cd, meshcat


def _settings(params, seed, scenario, overrides, limit, anatomy, localisation=None) -> dict:
    return {"units": [u.name for u in scenario.units], "force_gf": gram_force(params.force_command), "window_gf": [gram_force(v) for v in params.force_window],
            "dwell_s": params.dwell, "seed": seed, "engine": scenario.engine, "overrides": overrides,
            "localisation": None if localisation is None else {
                "noise_std_mm": localisation.noise_std * 1e3, "rate_hz": localisation.rate,
                "latency_s": localisation.latency},
            "navigator_period_s": params.period, "time_limit_s": limit,
            "wall_motion": None if (law := scenario.wall_motion.law()) is None else law.to_dict(),
            "anatomy": None if anatomy.procedural else str(anatomy.path)}


def _add_operator(handles: dict, scenario, heart, chosen_names: list, seed: int, dwell: float):
    """The ``add_systems`` hook of the operator's run: the simulated operator (world mapping,
    holding still for ``dwell`` on each touched target) and the force and tip loggers."""
    from pydrake.systems.primitives import LogVectorOutput

    from ballchain.experiments.teleop import vein_openings
    from ballchain.systems.simulated_operator import OperatorParams, SimulatedOperator

    def add(builder, ports):
        names, p_WT, n_W, radius = ports.targets
        chosen = [names.index(name) for name in chosen_names]
        cp = ports.chain
        params = OperatorParams(seed=seed, dwell=dwell, ball_radius=0.5 * cp.config.chain.ball_diameter,
                                target_radius=radius, p_WE=tuple(cp.p_WE), initial_length=scenario.insertion.initial,
                                max_length=cp.max_inserted_length(), keep_out=vein_openings(heart))
        op = builder.AddSystem(SimulatedOperator(cp.ball_body_indices[-1], cp.ball_body_indices[-2],
                                                 chosen_names, p_WT[chosen], n_W[chosen], params))
        builder.Connect(ports.body_poses, op.get_body_poses_input_port())
        (joystick,) = ports.joystick_inputs.values()
        builder.Connect(op.GetOutputPort("joystick"), joystick)
        builder.Connect(op.GetOutputPort("v_insert_cmd"), ports.feeder_command_input)
        handles["logs"] = [LogVectorOutput(port, builder, params.period) for port in (
            cp.get_tip_wall_force_output_port(), cp.get_ball_positions_output_port())]
        handles["operator"], handles["n_W"] = op, dict(zip(names, n_W))
        return {"operator": op}

    return add


def _operator_row(record, logs, context, n_W, params, ball_radius: float) -> dict:
    """One target's row of the operator's run: over its dwell (touch to the end of the hold)."""
    force, balls = (log.FindLog(context) for log in logs)
    t = force.sample_times()
    reached = record.t_touch is not None
    row = {"target": record.target, "reached": reached,
           "time_s": None if record.t_end is None else round(record.t_end - record.t_start, 3),
           "t_touch_s": None if not reached else round(record.t_touch, 3), "dwell_s": 0.0,
           "force_true_mean_gf": None, "force_true_min_gf": None, "force_true_max_gf": None,
           "in_window_fraction": None, "estimate_mean_error_gf": None, "estimate_worst_error_gf": None,
           "point": None, "reason": None}
    if not reached:
        row["reason"] = "gave up" if record.t_end is not None else "run ended"
        return row
    end = record.t_end if record.t_end is not None else t[-1]
    mask = (t > record.t_touch + 1e-9) & (t <= end + 1e-9)
    if not mask.any():
        return row
    f_W = force.data()[:3, mask].T
    true = f_W @ n_W
    lo, hi = params.force_window
    inside = (true >= lo) & (true <= hi)
    tip = balls.data()[-3:, mask].T
    mean_f = f_W.mean(axis=0)
    n_out = mean_f / np.linalg.norm(mean_f) if np.linalg.norm(mean_f) > 1e-9 else n_W
    row.update(dwell_s=round(float(end - record.t_touch), 3),
               force_true_mean_gf=round(gram_force(float(true.mean())), 3),
               force_true_min_gf=round(gram_force(float(true.min())), 3),
               force_true_max_gf=round(gram_force(float(true.max())), 3),
               in_window_fraction=round(float(np.mean(inside)), 4))
    row["point"] = {"name": record.target, "p_W": (tip.mean(axis=0) - ball_radius * n_out).tolist(),
                    "n_W": n_out.tolist(), "force_N": float(true.mean()), "duration_s": row["dwell_s"]}
    row["_in_window"] = inside
    return row


def _simulate_operator(task, anatomy, chosen, scenario, params, seed, progress, html, overrides) -> ProcedureResult:
    """The simulated operator's run on the targets ``chosen`` (indices in the anatomy's file order)."""
    from ballchain.systems.world_apply import world_draw

    from ballchain.systems.chain_simulation import (ChainMonitor, MakeStation, after_updates, near_ostium_rim,
                                                    run_station)

    heart = anatomy.atrium()
    names = [anatomy.target_names[k] for k in chosen]
    handles: dict = {}
    meshcat = None
    if html is not None:
        from ballchain.systems.chain_simulation import replay_meshcat

        meshcat = replay_meshcat()
    from ballchain.systems.simulated_operator import OperatorParams

    cd = MakeStation(_fed_every(scenario, OperatorParams().period), meshcat=meshcat, heart=heart,
                     add_systems=_add_operator(handles, scenario, heart, names, seed, params.dwell))
    op = handles["operator"]
    _check_batches(cd, op.params.period)
    limit = len(names) * (op.params.timeout + params.dwell) + 5.0
    monitor = ChainMonitor(cd, tolerate_sinking=lambda p: near_ostium_rim(heart, p))
    run = run_station(cd, duration=limit, monitor=monitor,
                      stop=after_updates(lambda c: op.is_done(op.GetMyContextFromRoot(c)), op.params.period),
                      progress=f"procedure {task or anatomy.name}/operator" if progress else None,
                      progress_step=0.5, html=html, meshcat=meshcat)
    records = {r.target: r for r in op.records(op.GetMyContextFromRoot(run.context))}
    ball_r = 0.5 * cd.chain.config.chain.ball_diameter
    rows = [_operator_row(records[name], handles["logs"], run.context, handles["n_W"][name], params, ball_r)
            if name in records else {"target": name, "reached": False, "time_s": None, "reason": "not reached"}
            for name in names]
    summary = _summary(rows, run, 0.0, [])
    return ProcedureResult(task=task, navigator="operator", rows=rows, summary=summary,
                           settings={**_settings(params, seed, scenario, overrides, limit, anatomy),
                                     "world": None if (world := world_draw(scenario)) is None else world.to_dict()},
                           html=None if html is None else str(html)), cd, meshcat
