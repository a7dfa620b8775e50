"""Equilibrium shape of a chain in a uniform field, reached by rotating the field from +x.

The canonical problem of docs/design.md (2.3): ball 1 held at the origin with its dipole along +x,
the field in the x-y plane at ``--field-angle-deg`` from +x, reached by continuation from the
straight chain in steps of at most ``--step-deg`` (as a rotating magnet moves the chain).
"""

from __future__ import annotations

import argparse
import sys

import numpy as np
from tqdm import tqdm

from ballchain.commands._common import add_json_flag, check_in, finite_float, float_in, int_in, print_json
from ballchain.drake_models.errors import UserInputError
from ballchain.drake_models.field_sources import UniformField
from ballchain.drake_models.params import BallChain, Sleeve
from ballchain.optimization.statics import ChainStatics, rotation_path, tip_angle_deg


MAX_BALLS = 200  # dense Hessians: 200 balls take about 0.5 GB
MAX_FIELD_MT = 1000.0
MIN_STEP_DEG = 0.1  # at most 7200 continuation steps over the widest angle


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--balls", type=int_in(1, MAX_BALLS), default=16, help=f"number of balls (1..{MAX_BALLS})")
    parser.add_argument("--field-mT", type=float_in(0.0, MAX_FIELD_MT), default=23.0,
                        help=f"field magnitude [mT] (0..{MAX_FIELD_MT:g})")
    parser.add_argument("--field-angle-deg", type=float_in(-360.0, 360.0), default=90.0,
                        help="field angle from +x towards +y [deg] (-360..360)")
    parser.add_argument("--step-deg", type=float_in(MIN_STEP_DEG, 90.0), default=22.5,
                        help=f"largest continuation step of the field angle [deg] ({MIN_STEP_DEG:g}..90)")
    parser.add_argument("--gravity", action="store_true", help="gravity along -z")
    parser.add_argument("--sleeve", action="store_true", help="Dragon Skin sleeve (E = 0.15 MPa)")
    parser.add_argument("--method", choices=["newton", "snopt"], default="newton",
                        help="statics solver")
    add_json_flag(parser)


def run(*, balls: int, field_mT: float, field_angle_deg: float, step_deg: float = 22.5,
        gravity: bool = False, sleeve: bool = False, method: str = "newton") -> dict:
    """Solve and return the JSON-ready result (positions in mm)."""
    if isinstance(balls, bool) or not isinstance(balls, (int, np.integer)) or not 1 <= balls <= MAX_BALLS:
        raise UserInputError(f"--balls must be an integer in 1..{MAX_BALLS}, got {balls!r}")
    check_in("--field-mT", field_mT, 0.0, MAX_FIELD_MT, unit="mT")
    check_in("--field-angle-deg", field_angle_deg, -360.0, 360.0, unit="deg")
    check_in("--step-deg", step_deg, MIN_STEP_DEG, 90.0, unit="deg")
    if method not in ("newton", "snopt"):
        raise UserInputError(f"--method must be 'newton' or 'snopt', got {method!r}")
    chain = BallChain(n_balls=balls, sleeve=Sleeve() if sleeve else None)
    solver = ChainStatics(chain, gravity=gravity, method=method)
    angles = rotation_path(0.0, field_angle_deg, step_deg)
    result = None
    total_time = 0.0
    # Progress only for long continuations (a few hundred solves take seconds).
    for angle in tqdm(angles, desc="statics", unit="step", disable=len(angles) < 200, file=sys.stderr):
        result = solver.solve_or_raise(UniformField.in_plane(field_mT * 1e-3, np.radians(angle)), result)
        total_time += result.solve_time
    direction = [np.cos(np.radians(field_angle_deg)), np.sin(np.radians(field_angle_deg)), 0.0]
    return {
        "positions_mm": result.positions * 1e3,
        "dipoles": result.dipoles,
        "tip_angle_deg": tip_angle_deg(result, direction) if field_mT > 0 else None,
        "energy_J": result.energy,
        "converged": result.converged,
        "reason": result.reason,
        "solver": result.solver,
        "iterations": result.iterations,
        "solve_time_s": result.solve_time,
        "continuation_steps": len(angles),
        "continuation_time_s": total_time,
    }


def main(args: argparse.Namespace) -> int:
    data = run(balls=args.balls, field_mT=args.field_mT, field_angle_deg=args.field_angle_deg,
               step_deg=args.step_deg, gravity=args.gravity, sleeve=args.sleeve, method=args.method)
    if args.json:
        print_json(data)
        return 0
    tip = data["positions_mm"][-1]
    angle = "-" if data["tip_angle_deg"] is None else f"{data['tip_angle_deg']:.3f} deg"
    print(f"{args.balls} balls, {args.field_mT} mT at {args.field_angle_deg} deg: tip at "
          f"({tip[0]:.2f}, {tip[1]:.2f}, {tip[2]:.2f}) mm, tip angle {angle}, "
          f"energy {data['energy_J']:.4e} J ({data['reason']}, {data['solve_time_s'] * 1e3:.1f} ms)")
    return 0
