"""The world applied where the station builds its physics (``drake_models.world``, the scenario's
``world:`` block, ``world_scenario``).

The quasi-static engine (``quasi_static_engine.StaticsChainModel.add_to``) plays the drawn world:

* the unit magnets: ``magnet_errors`` sits between the units' ``magnet_states`` and the engine's
  input, moving each centre by its drawn offset and turning each dipole by its drawn rotation;
  each port magnet's remanence is scaled (``perturbed_coupling``). The units themselves (their
  Hall sensors, estimators, controllers) and every model built from their configurations keep
  the nominal centres and magnets;
* the chain: every ball's diameter and remanence scaled (one lot, ``perturbed_config``);
* the anatomy's registration: the wall and the sheath in it moved together by the drawn offset
  relative to the magnets, the wall's grid scaled and turned about the sheath exit
  (``perturbed_wall``; the turn by ``PosedWall``: the grid stays axis-aligned);
* the sheath exit moved across its axis by its drawn offset (the engine's ``p_WE`` and sheath,
  ``perturbed_exit``);

and the procedure's tip tracker adds the drawn bias to its readings (``procedure_runs``).
The atrium object, the unit configurations and ``BallChain()`` that the planner, the navigator's
``TipForceEstimator`` and the simulated operator read stay nominal: the world is what they do
not know. A world with nothing perturbed (``world: none``, the default) adds nothing: the station
is today's, number for number.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from pydrake.systems.primitives import AffineSystem

from ballchain.drake_models.atrium_sdf import AtriumSDF
from ballchain.drake_models.world import PosedWall, WorldDraw, draw_world
from ballchain.systems.world_scenario import world_seed


def world_draw(scenario, n_magnets: int | None = None) -> WorldDraw | None:
    """The scenario's drawn world (``draw_world`` with ``world_scenario.world_seed``), or None
    when nothing is perturbed. ``n_magnets``: the unit magnets (default: the scenario's units)."""
    w = scenario.world
    if not w.perturbed:
        return None
    n = len(scenario.units) if n_magnets is None else n_magnets
    return draw_world(w.magnitudes(), world_seed(scenario), n)


def perturbed_config(config, draw: WorldDraw):
    """The chain's configuration (``ChainPlantConfig``) with the drawn balls."""
    chain = config.chain
    chain = replace(chain, ball_diameter=chain.ball_diameter * draw.ball_diameter_scale,
                    remanence=chain.remanence * draw.ball_remanence_scale)
    return replace(config, chain=chain)


def perturbed_coupling(coupling, draw: WorldDraw):
    """The field coupling (``chain_model.FieldCoupling``) with each port magnet's drawn remanence."""
    magnets = [replace(m, remanence=m.remanence * s) for m, s in zip(coupling.port_magnets, draw.magnet_scales)]
    return replace(coupling, port_magnets=magnets)


def perturbed_wall(sdf, draw: WorldDraw, p_WE):
    """The wall's signed distance scaled by ``anatomy_scale`` about the sheath exit ``p_WE`` (the
    septal puncture stays where the sheath crosses it), turned by the anatomy's rotation R about
    it too and moved by ``anatomy_offset`` t: ``s * sdf(c + R^T (p - t - c) / s)``; the scale is
    exact on the grid (origin, spacing, values and band scaled), the turn a ``PosedWall`` around
    it. A wall that is not a grid (a plane) is only turned and moved. No rotation drawn: no
    ``PosedWall`` (the wall is the grid, bit for bit as before)."""
    if sdf is None:
        return None
    offset = np.asarray(draw.anatomy_offset, float)
    s = float(draw.anatomy_scale)
    if isinstance(sdf, AtriumSDF) and s != 1.0:
        c = np.asarray(p_WE, float)
        sdf = AtriumSDF(c + s * (np.asarray(sdf.origin, float) - c), sdf.spacing * s, sdf.values * s, sdf.band * s,
                        key=f"{sdf.key}-scaled-{s!r}")
    if np.any(np.asarray(draw.anatomy_rotation, float) != 0.0):
        sdf = PosedWall.about(sdf, draw.anatomy_rotation_matrix(), p_WE)
    return sdf.translated(offset) if np.any(offset != 0.0) else sdf


def perturbed_exit(p_WE, axis_W, draw: WorldDraw) -> np.ndarray:
    """The world's sheath exit: moved with the anatomy (``anatomy_offset``: the wall and the sheath
    in it together) and by the sheath's own registration error across its axis
    (``sheath_exit_offset`` without its component along ``axis_W``: the puncture elsewhere on
    the septum; along the axis it would push the exit into the wall or off it)."""
    u = np.asarray(axis_W, float) / np.linalg.norm(axis_W)
    e = np.asarray(draw.sheath_exit_offset, float)
    return np.asarray(p_WE, float) + np.asarray(draw.anatomy_offset, float) + e - (e @ u) * u


def magnet_errors(draw: WorldDraw, n_magnets: int) -> AffineSystem:
    """``world_magnets``: the magnet states the engine feels from the units' (6 per magnet:
    centre, dipole): each centre plus its offset, each dipole turned by its rotation. A
    feedthrough ``AffineSystem`` (no state)."""
    D = np.zeros((6 * n_magnets, 6 * n_magnets))
    y0 = np.zeros(6 * n_magnets)
    for k in range(n_magnets):
        D[6 * k:6 * k + 3, 6 * k:6 * k + 3] = np.eye(3)
        D[6 * k + 3:6 * k + 6, 6 * k + 3:6 * k + 6] = draw.magnet_rotation(k)
        y0[6 * k:6 * k + 3] = draw.magnet_offsets[k]
    n = 6 * n_magnets
    system = AffineSystem(np.zeros((0, 0)), np.zeros((0, n)), np.zeros(0), np.zeros((n, 0)), D, y0)
    system.set_name("world_magnets")
    return system


def apply_world_statics(scenario, config, coupling):
    """(config, coupling, draw) of the quasi-static engine in the scenario's world (the inputs
    themselves and None when nothing is perturbed)."""
    draw = world_draw(scenario, len(coupling.port_magnets))
    if draw is None:
        return config, coupling, None
    return perturbed_config(config, draw), perturbed_coupling(coupling, draw), draw


def biased_reading(builder, port, bias):
    """``port`` (a tracker's reading, 3) plus the world's constant ``bias`` (3,) [m]
    (``world_tracker_bias``, a feedthrough ``AffineSystem``); ``port`` itself for a zero bias."""
    bias = np.asarray(bias, float)
    if not np.any(bias != 0.0):
        return port
    system = builder.AddSystem(AffineSystem(np.zeros((0, 0)), np.zeros((0, 3)), np.zeros(0), np.zeros((3, 0)),
                                            np.eye(3), bias))
    system.set_name("world_tracker_bias")
    builder.Connect(port, system.get_input_port())
    return system.get_output_port()


def monitor_offsets(draw: WorldDraw, p_WE, p_WE_world, p: np.ndarray, motion=None):
    """What the chain monitor subtracts from the balls ``p`` (n, 3) [m] to see them from the
    nominal sheath and the nominal wall (``StaticsChainModel.anatomy_offsets``): (the sheath's
    displacement (3,), each ball's displacement from its place in the nominal wall's frame
    (n, 3)), the world's (``perturbed_wall``: ``c + R^T (p - t - c) / s``, ``perturbed_exit``) after the moving wall's
    ``motion`` = (heart offset, wall offset) when it moves."""
    sheath = np.asarray(p_WE_world, float) - np.asarray(p_WE, float)
    wall = np.zeros(3)
    if motion is not None:
        sheath, wall = sheath + motion[0], np.asarray(motion[1], float)
    c = np.asarray(p_WE, float)
    p = np.asarray(p, float)
    R = draw.anatomy_rotation_matrix()
    p_H = c + ((p - wall - np.asarray(draw.anatomy_offset, float) - c) @ R) / float(draw.anatomy_scale)
    return sheath, p - p_H
