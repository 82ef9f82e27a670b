#!/usr/bin/python3
# SPDX-License-Identifier: GPL-3.0-or-later
"""How the pose correction's time, and the map's, grow with the survey's length.

A corridor of each length in --lengths-m (2 m wide, closed 3 m past both ends, door frames
every 4 m), surveyed every 0.2 m with exact echoes from the true poses and an odometry 1 %
long drifting 0.5° per metre (testing.drifting_corridor, the issue's drift). Each is mapped
twice in this process: as WallFusion does it, and with one piece swapped for a plain
reference, the odometry's standard errors from a dense pseudo-inverse of JᵀJ (what the
adjustment did before `_last_standard_errors`). Prints the seconds of the "pose correction"
phase, per pose, their ratio, and the trajectory's RMS against the truth (both maps must
agree: the reference changes the speed, not the answer); then, for the first variant, the
"walls and landmarks" phase (the wall extraction and point landmarks of every map pass) and
the whole fusion.

Usage: benchmarks/bench_pose_correction.py [--lengths-m 20 80 160] [--repeat 1]
"""
import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse  # noqa: E402
import importlib  # noqa: E402

import numpy as np  # noqa: E402

from gnuradio.thrumapper.testing import drifting_corridor, exact_echoes  # noqa: E402
from gnuradio.thrumapper.wall_fusion import FusionSettings, RadarGeometry, WallFusion  # noqa: E402

# the module, not the block of the same name the package exports
fusion_module = importlib.import_module("gnuradio.thrumapper.wall_fusion")
RADAR = RadarGeometry.uca_pair(subcarriers=64)


def dense_standard_errors(jac, count):
    """The reference: the last diagonal entries of the dense pseudo-inverse of JᵀJ."""
    normal = (jac.T @ jac).toarray()
    return np.sqrt(np.maximum(np.diag(np.linalg.pinv(normal))[-count:], 0.0))


def map_corridor(length_m):
    """(pose correction s, poses, trajectory RMS m, rounds, walls and landmarks s, fusion s)
    of one map of the corridor."""
    true, reported, walls, frames = drifting_corridor(length_m)
    fusion = WallFusion(RADAR, FusionSettings(material=None))  # exact echoes: no slab shift
    for pose_true, pose_reported in zip(true, reported):
        fusion.add(pose_reported, exact_echoes(pose_true, walls, RADAR, points=frames))
    fused = fusion.build_map()
    rms = float(np.sqrt(np.mean(np.sum((fused.trajectory[:, :2] - true[:, :2]) ** 2, axis=1))))
    phases = fused.stats["fusion_phases_s"]
    return (phases["pose correction"], len(true), rms, fused.stats["adjustment_rounds"],
            phases["walls and landmarks"], fused.stats["elapsed_s"])


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--lengths-m", type=float, nargs="+", default=[20.0, 80.0, 160.0],
                        help="corridor lengths to survey (0.2 m between poses)")
    parser.add_argument("--repeat", type=int, default=1, help="maps per length and variant (the fastest is kept)")
    args = parser.parse_args(argv)
    sparse = fusion_module._last_standard_errors
    print(f"{'length':>8} {'poses':>6} {'rounds':>6} {'sparse s':>9} {'ms/pose':>8} {'dense s':>8} {'ms/pose':>8}"
          f" {'ratio':>6} {'traj sparse':>11} {'traj dense':>10} {'walls s':>8} {'fusion s':>9}")
    for length_m in args.lengths_m:
        results = {}
        for name, errors in (("sparse", sparse), ("dense", dense_standard_errors)):
            fusion_module._last_standard_errors = errors
            try:
                runs = [map_corridor(length_m) for _ in range(args.repeat)]
            finally:
                fusion_module._last_standard_errors = sparse
            results[name] = min(runs, key=lambda run: run[0])
        (t_s, poses, rms_s, rounds, walls_s, fusion_s), (t_d, _, rms_d, *_) = results["sparse"], results["dense"]
        print(f"{length_m:7.0f}m {poses:6d} {rounds:6d} {t_s:9.2f} {1e3 * t_s / poses:8.1f} {t_d:8.2f}"
              f" {1e3 * t_d / poses:8.1f} {t_d / t_s:6.2f} {rms_s:10.4f}m {rms_d:9.4f}m {walls_s:8.2f} {fusion_s:9.2f}",
              flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
