"""Cost of a large user anatomy mesh, stage by stage: read and validate (with the quadric
decimation above ``atrium_mesh.DECIMATE_ABOVE`` triangles), the ``UserAtrium`` (trees, shells,
wall), and a short run on each engine (the plant registers the wall's tetrahedra; the statics
engine builds the signed-distance grid), each with a fresh cache so nothing is reused.

The mesh is a sphere of 25 mm radius made by trimesh (an icosphere of order ``--order``: 7 gives
327,680 triangles, the size of a fine segmentation). Printed: wall and process CPU time of every
stage (the machine is shared: wall time counts the waits) and the triangle counts.

    python benchmarks/large_anatomy_bench.py --order 7
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path


def stage(name: str, start: tuple[float, float]) -> tuple[float, float]:
    wall, cpu = time.perf_counter() - start[0], time.process_time() - start[1]
    print(f"{name:<34} {wall:7.1f} s wall {cpu:7.1f} s CPU (cumulative)", file=sys.stderr, flush=True)
    return wall, cpu


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--order", type=int, default=7, help="icosphere subdivisions (7: 327,680 triangles)")
    parser.add_argument("--engines", nargs="*", default=["plant", "statics"])
    args = parser.parse_args()
    import trimesh

    folder = Path(tempfile.mkdtemp(prefix="large_anatomy_"))
    path = folder / "sphere_mm.stl"
    trimesh.creation.icosphere(args.order, radius=25.0).export(path)
    for engine in args.engines:
        os.environ["BALLCHAIN_CACHE"] = str(folder / f"cache_{engine}")  # nothing reused
        from ballchain.drake_models.atrium_mesh import UserAtrium, load_atrium_surface
        from ballchain.systems.chain_scenario import load_scenario
        from ballchain.systems.chain_simulation import run_simulation

        start = time.perf_counter(), time.process_time()
        surface = load_atrium_surface(path, "mm")
        stage(f"{engine}: read, validate, decimate", start)
        heart = UserAtrium(surface, [-25e-3, 0.0, 0.0])
        stage(f"{engine}: UserAtrium", start)
        scenario = load_scenario("heart_no_field", f"{{engine: {engine}, insertion: {{initial: 0.01, final: 0.012}}}}")
        run_simulation(scenario=scenario, duration=0.05, heart=heart)
        stage(f"{engine}: build and 0.05 s run", start)
        print(f"{engine}: {'; '.join(surface.notes)}", file=sys.stderr)


if __name__ == "__main__":
    main()
