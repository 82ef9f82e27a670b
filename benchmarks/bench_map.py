#!/usr/bin/python3
# SPDX-License-Identifier: GPL-3.0-or-later
"""thrumapper-map speed on the office scene: seconds per pose, and where the time goes.

Simulates examples/scenes/office_floor.yaml (100 poses x 4 frames; reused from --out when it
is there), then runs the mapping chain of thrumapper-map (cli_map.map_survey: RX calibration,
JADE on every pose group, wall fusion) --repeat times on one core (BLAS threads pinned to 1)
and prints the time of each phase, the fusion's own phases, and with --profile the functions
that take the most time.

Usage: benchmarks/bench_map.py [--out DIR] [--repeat N] [--profile] [--stages S]
"""
import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("MKL_NUM_THREADS", "1")

import argparse  # noqa: E402
import contextlib  # noqa: E402
import io  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402

from gnuradio.thrumapper import cli_map, cli_sim, survey  # noqa: E402

HERE = os.path.dirname(os.path.abspath(__file__))
SCENE = os.path.join(HERE, "..", "examples", "scenes", "office_floor.yaml")
SYSTEM_DELAY_S = 31e-9  # the scene's; the nulled survey cannot measure it (docs/mapping.md)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default="out/bench_map", help="where the simulated survey is kept")
    parser.add_argument("--repeat", type=int, default=2, help="runs to time (the fastest is reported)")
    parser.add_argument("--profile", action="store_true", help="also print the top functions (cProfile)")
    parser.add_argument("--stages", type=int, default=1, help="JADE successive-cancellation stages")
    args = parser.parse_args(argv)
    meta = os.path.join(args.out, "office_floor.sigmf-meta")
    if not os.path.exists(meta):
        os.makedirs(args.out, exist_ok=True)
        with contextlib.redirect_stdout(io.StringIO()):
            cli_sim.main([SCENE, "--out", args.out, "--quiet"])
    best = None
    for _ in range(max(1, args.repeat)):
        sv = survey.read_survey(meta)
        timings = {}
        started = time.perf_counter()
        fused, _ = cli_map.map_survey(sv, settings=cli_map.jade_settings(stages=args.stages),
                                      system_delay_s=SYSTEM_DELAY_S, timings=timings)
        total = time.perf_counter() - started
        if best is None or total < best[0]:
            best = (total, timings, fused.stats)
    total, timings, stats = best
    poses = stats["poses"]
    print(f"office_floor: {poses} poses, {stats['echoes']} echoes -> {stats['walls']} walls; "
          f"JADE stages {args.stages}; best of {args.repeat}")
    print(f"{'phase':32s}{'s':>9s}{'s/pose':>10s}{'share':>8s}")
    rows = [("RX calibration", timings.get("calibration_s", 0.0)), ("system delay", timings.get("system_delay_s", 0.0)),
            ("JADE (all pose groups)", timings.get("jade_s", 0.0)), ("wall fusion", timings.get("fusion_s", 0.0))]
    for name, seconds in rows:
        print(f"{name:32s}{seconds:9.3f}{seconds / poses:10.4f}{100 * seconds / total:7.1f}%")
    print(f"{'total':32s}{total:9.3f}{total / poses:10.4f}")
    print("\nwall fusion, by phase:")
    for name, seconds in sorted(stats.get("fusion_phases_s", {}).items(), key=lambda kv: -kv[1]):
        print(f"  {name:30s}{seconds:9.3f}{seconds / poses:10.4f}{100 * seconds / max(timings['fusion_s'], 1e-9):7.1f}%")
    if args.profile:
        import cProfile
        import pstats
        profiler = cProfile.Profile()
        sv = survey.read_survey(meta)
        profiler.enable()
        cli_map.map_survey(sv, settings=cli_map.jade_settings(stages=args.stages), system_delay_s=SYSTEM_DELAY_S)
        profiler.disable()
        pstats.Stats(profiler, stream=sys.stdout).sort_stats("cumulative").print_stats(25)
    return 0


if __name__ == "__main__":
    sys.exit(main())
