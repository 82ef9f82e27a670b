#!/usr/bin/python3
# SPDX-License-Identifier: GPL-3.0-or-later
"""What the odometry's estimated scale and heading drift cost the trajectory.

The pose adjustment estimates the odometry's scale error and its heading drift per metre with
the poses (WallFusion._adjust_poses). This maps each seed twice from the same JADE results:

- as mapped: as thrumapper-map does with its default options (cli_map.map_survey);
- systematic known: the odometry first corrected by the scene's own scale error and heading
  drift (the simulator's odometry model), and the adjustment told there is none left
  (SYSTEMATIC_SIGNIFICANCE infinite: held at none). The per-step noise stays.

and prints per seed the drift the adjustment estimated against the scene's, and for both maps
the trajectory's RMS error, its heading error at the quarters of the track (estimate less
truth, degrees) and its cross-track error at the track's end. The gap between the two RMS
columns is what the drift and scale estimates cost (docs/mapping.md, "The drift
and the scale, given").

With --true-odometry, a third map: the true poses handed in as the odometry (no systematic
error, no per-step noise) and the adjustment run as thrumapper-map runs it. Whatever drift it
estimates there, and whatever the track's error, comes from the echoes alone: the per-pose
fits' runs of bias along the walls (docs/mapping.md, "Four more tries at the class rule and
the trajectory").

Usage: benchmarks/odometry_systematic.py [--out DIR] [--scene office_floor] [--seeds own 1 2 ...]
                                         [--true-odometry]
       (PYTHONPATH=build/test_modules, or the module installed; a few minutes a seed)
"""
import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import json  # noqa: E402
import math  # noqa: E402
import sys  # noqa: E402

import numpy as np  # noqa: E402

from gnuradio.thrumapper import scene as scene_mod  # noqa: E402
from gnuradio.thrumapper.wall_fusion import _compose, _relative  # noqa: E402

import office_surveys  # noqa: E402


def corrected_odometry(poses, scale_error, drift_deg_per_m):
    """The odometry's poses (P, 3) with its systematic errors taken out step by step: each
    step's motion divided by (1 + scale_error), its turn less the drift over its length."""
    out = np.array(poses, float)
    for i in range(1, len(out)):
        step = _relative(poses[i - 1], poses[i])
        step[:2] = step[:2] / (1.0 + scale_error)
        step[2] -= math.radians(drift_deg_per_m) * math.hypot(step[0], step[1])
        out[i] = _compose(out[i - 1], step)
    return out


def true_trajectory(truth_path):
    """The truth's trajectory: (positions (P, 2), headings (P,), rad)."""
    with open(truth_path) as f:
        truth = json.load(f)
    feature = [f for f in truth["features"] if f["properties"].get("kind") == "trajectory"][0]
    return np.array(feature["geometry"]["coordinates"], float), np.array(feature["properties"]["headings_rad"], float)


def trajectory_errors(fused, true_xy, true_h):
    """(RMS m, heading error deg at 1/4, 1/2, 3/4 and the end of the track, cross-track error
    at the end, m). The first pose is the truth's, so its heading error is none."""
    xy = np.array(fused.trajectory, float)[:, :2]
    heading = np.array(fused.trajectory, float)[:, 2]
    if xy.shape != true_xy.shape:
        raise SystemExit(f"the map has {len(xy)} poses, the truth {len(true_xy)}")
    error = xy - true_xy
    rms = float(np.sqrt(np.mean(np.sum(error ** 2, axis=1))))
    turn = np.degrees(np.angle(np.exp(1j * (heading - true_h))))
    quarters = [turn[int(round(q * (len(turn) - 1)))] for q in (0.25, 0.5, 0.75, 1.0)]
    direction = true_xy[-1] - true_xy[-2]
    direction /= np.hypot(*direction)
    cross = float(error[-1, 1] * direction[0] - error[-1, 0] * direction[1])
    return rms, quarters, cross


def drift_of(fused):
    """The heading drift the map's adjustment estimated (deg/m, 0 where held at none), as text."""
    drift = fused.stats.get("odometry_drift_deg_per_m")
    return "–" if drift is None else f"{drift:.3f}"


def main(argv=None):
    parser = office_surveys.parser_for(__doc__, "out/odometry_systematic")
    parser.add_argument("--true-odometry", action="store_true",
                        help="also map each seed with the true poses as its odometry (the adjustment on)")
    args = parser.parse_args(argv)
    scene_path = office_surveys.scene_path(parser, args)
    odometry = scene_mod.load_scene(scene_path).odometry
    print(f"{args.scene}: odometry scale error {odometry['scale_error']:g}, heading drift "
          f"{odometry['heading_drift_deg_per_m']:g} deg/m\n")
    header = ("| seed | drift estimated, deg/m | as mapped: RMS m | heading error at 1/4, 1/2, 3/4, end, deg | "
              "cross at end m | systematic known: RMS m | heading error, deg | cross at end m |")
    rule = "|---|---|---|---|---|---|---|---|"
    if args.true_odometry:
        header += " true odometry: drift estimated, deg/m | RMS m | heading error, deg | cross at end m |"
        rule += "---|---|---|---|"
    print(header)
    print(rule)
    for seed in args.seeds:
        fused, info, truth = office_surveys.mapped(scene_path, args.scene, seed, args.out)
        poses = corrected_odometry(np.array([r[0] for r in info["jade_results"]], float), odometry["scale_error"],
                                   odometry["heading_drift_deg_per_m"])
        fused_known = office_surveys.remapped(info, poses, SYSTEMATIC_SIGNIFICANCE=math.inf)
        true_xy, true_h = true_trajectory(truth)
        maps = [fused, fused_known]
        if args.true_odometry:
            maps.append(office_surveys.remapped(info, np.column_stack((true_xy, true_h))))
        rows = []
        for f in maps:
            rms, quarters, cross = trajectory_errors(f, true_xy, true_h)
            rows.append(f"{rms:.3f} | " + " / ".join(f"{q:+.2f}" for q in quarters) + f" | {cross:+.3f}")
        if args.true_odometry:
            rows[2] = f"{drift_of(maps[2])} | {rows[2]}"
        print(f"| {seed} | {drift_of(fused)} | " + " | ".join(rows) + " |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
