"""Equilibrium shape of a chain in a uniform field, reached by rotating the field from +x.

The canonical problem of docs/design.md (2.3): ball 1 held at the origin with its dipole along +x,
the field in the x-y plane at ``--field-angle-deg`` from +x, reached by continuation from the
straight chain in steps of at most ``--step-deg`` (as a rotating magnet moves the chain).
"""

from __future__ import annotations

import argparse

import numpy as np

from ballchain.commands._common import add_json_flag, finite_float, positive_int, print_json
from ballchain.drake_models.field_sources import UniformField
from ballchain.drake_models.params import BallChain, Sleeve
from ballchain.optimization.statics import ChainStatics, rotation_path, tip_angle_deg


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--balls", type=positive_int, default=16, help="number of balls (>= 1)")
    parser.add_argument("--field-mT", type=finite_float, default=23.0, help="field magnitude [mT]")
    parser.add_argument("--field-angle-deg", type=finite_float, default=90.0,
                        help="field angle from +x towards +y [deg]")
    parser.add_argument("--step-deg", type=finite_float, default=22.5,
                        help="largest continuation step of the field angle [deg]")
    parser.add_argument("--gravity", action="store_true", help="gravity along -z")
    parser.add_argument("--sleeve", action="store_true", help="Dragon Skin sleeve (E = 0.15 MPa)")
    parser.add_argument("--method", choices=["newton", "snopt"], default="newton",
                        help="statics solver")
    add_json_flag(parser)


def run(*, balls: int, field_mT: float, field_angle_deg: float, step_deg: float = 22.5,
        gravity: bool = False, sleeve: bool = False, method: str = "newton") -> dict:
    """Solve and return the JSON-ready result (positions in mm)."""
    if field_mT < 0:
        raise ValueError(f"--field-mT must be >= 0, got {field_mT}")
    if step_deg <= 0:
        raise ValueError(f"--step-deg must be positive, got {step_deg}")
    chain = BallChain(n_balls=balls, sleeve=Sleeve() if sleeve else None)
    solver = ChainStatics(chain, gravity=gravity, method=method)
    angles = rotation_path(0.0, field_angle_deg, step_deg)
    result = None
    total_time = 0.0
    for angle in angles:
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
    print(f"{args.balls} balls, {args.field_mT} mT at {args.field_angle_deg} deg: tip at "
          f"({tip[0]:.2f}, {tip[1]:.2f}, {tip[2]:.2f}) mm, tip angle {data['tip_angle_deg']:.3f} deg, "
          f"energy {data['energy_J']:.4e} J ({data['reason']}, {data['solve_time_s'] * 1e3:.1f} ms)")
    return 0
