#!/usr/bin/python3
# SPDX-License-Identifier: GPL-3.0-or-later
"""How well the walls' carrier phase measures the robot's motion, and what it does to the
trajectory (docs/mapping.md, "The walls' carrier phase").

For each seed of an office scene (simulated once, thrumapper-sim --seed) and its JADE results:

- the measurement: the survey's CSI at the TRUE poses against the truth's line-of-sight walls
  (their faces): each wall's path change from a pose to the next on the carrier's phase
  (WallFusion._phase_steps) less the geometric one (the image of the TX centre in the face),
  per wall: steps, median and MAD of the error in mm, and its trend along the wall turned into
  the heading rate it would put into the adjustment (deg/m);
- the adjustment: the survey mapped from the same JADE results with the phase steps
  (WallFusion.PHASE_STEP_SIGMA_M) and without them: the drift the adjustment estimated against
  the one the odometry's headings show (fitted on the truth's), the trajectory RMS and the
  heading, cross-track and along-track errors at the track's end.

Usage: benchmarks/phase_steps.py [--out DIR] [--scene office_floor] [--seeds own 1 2 ...] [--sigma-m 0.003]
       (PYTHONPATH=build/test_modules, or the module installed; about a minute and a half a seed)
"""
import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse  # noqa: E402
import dataclasses  # noqa: E402
import math  # noqa: E402
import sys  # noqa: E402

import numpy as np  # noqa: E402

from gnuradio.thrumapper import evaluation  # noqa: E402
from gnuradio.thrumapper.wall_fusion import LOS, WallFusion  # noqa: E402

import office_surveys  # noqa: E402
from odometry_systematic import trajectory_errors, true_trajectory  # noqa: E402


def truth_walls(truth_path, track_xy, min_length_m=2.0):
    """The truth's line-of-sight walls of at least min_length_m as the fusion's wall dicts,
    each facing the track's middle."""
    middle = np.mean(track_xy, axis=0)
    walls = []
    for wall in evaluation.load_map(truth_path, "truth").walls:
        if wall["class"] != "line_of_sight":
            continue
        a, b = np.asarray(wall["coordinates"][0], float), np.asarray(wall["coordinates"][-1], float)
        length = float(np.hypot(*(b - a)))
        if length < min_length_m:
            continue
        direction = (b - a) / length
        normal = np.array([-direction[1], direction[0]])
        centre = 0.5 * (a + b)
        if (middle - centre) @ normal < 0:
            normal = -normal
        walls.append({"centre": centre, "normal": normal, "direction": direction, "t0": -length / 2, "t1": length / 2})
    return walls


def measured_against_truth(info, true_poses, walls):
    """Rows (wall label, steps, median mm, MAD mm, heading-rate error deg/m) of the phase
    steps at the true poses against the truth's walls (the survey of `info`, mapped())."""
    fusion = info["fusion"]
    probe = WallFusion(fusion.radar, dataclasses.replace(fusion.settings))
    probe.enable_csi_refinement(info["system_delay_s"])
    # the CSI alone, without JADE's paths: at the true walls the estimator's paths of them
    # would not count as theirs and would be projected out of their echoes
    for pose, result in zip(true_poses, info["jade_results"]):
        probe.add(pose, [], *result[2:])
    steps = probe._phase_steps({"walls": walls}, true_poses, [LOS] * len(walls), {k: k for k in range(len(walls))})
    rows = []
    for k, w in enumerate(walls):
        mine = [q for q in steps if q[4] == k]
        if not mine:
            continue
        g = np.array([q[0] for q in mine])
        measured = np.array([q[2] for q in mine])
        n = np.tile(w["normal"], (g.size, 1))
        offset = np.full(g.size, float(w["centre"] @ w["normal"]))
        true = probe._bistatic_lengths(true_poses[g + 1], n, offset) - probe._bistatic_lengths(true_poses[g], n, offset)
        error_mm = (measured - true) * 1e3
        median = float(np.median(error_mm))
        good = np.abs(error_mm - median) < 10.0
        # a steady drift of the error along the wall is what would bend the heading: d(path
        # step)/d(heading) is about twice the step length across a wall along the track
        step_m = float(np.median(np.hypot(*(true_poses[g + 1, :2] - true_poses[g, :2]).T)))
        trend = np.polyfit(g[good], error_mm[good], 1)[0] if np.count_nonzero(good) > 3 else float("nan")
        rate = math.degrees(trend * 1e-3 / (2.0 * step_m)) / step_m
        ends = w["centre"] + np.outer([w["t0"], w["t1"]], w["direction"])
        label = f"({ends[0][0]:.1f}, {ends[0][1]:.1f})-({ends[1][0]:.1f}, {ends[1][1]:.1f})"
        rows.append((label, g.size, median, float(np.median(np.abs(error_mm - median))), rate))
    return rows


def trajectory_figures(fused, true_xy, true_h, odometry):
    """(drift estimated deg/m, drift the odometry shows deg/m, RMS m, heading error at the
    end deg, cross-track and along-track error at the end m)."""
    rms, quarters, cross = trajectory_errors(fused, true_xy, true_h)
    direction = true_xy[-1] - true_xy[-2]
    along = float((np.array(fused.trajectory, float)[-1, :2] - true_xy[-1]) @ direction / np.hypot(*direction))
    travelled = np.concatenate(([0.0], np.cumsum(np.hypot(*np.diff(odometry[:, :2], axis=0).T))))
    shown = np.unwrap(odometry[:, 2]) - np.unwrap(true_h)
    realized = math.degrees(np.polyfit(travelled, shown - shown[0], 1)[0])
    return fused.stats.get("odometry_drift_deg_per_m"), realized, rms, quarters[-1], cross, along


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter,
                                     epilog="\n\n".join(__doc__.split("\n\n")[1:]))
    office_surveys.add_arguments(parser, "out/phase_steps")
    parser.add_argument("--sigma-m", type=float, default=0.003,
                        help="WallFusion.PHASE_STEP_SIGMA_M of the map with the phase steps (default 0.003)")
    args = parser.parse_args(argv)
    if not args.sigma_m > 0:
        parser.error(f"--sigma-m: expected a positive noise in metres, got {args.sigma_m}")
    scene_path = office_surveys.scene_path(parser, args)
    measurement, adjustment = [], []
    for seed in args.seeds:
        fused, info, truth = office_surveys.mapped(scene_path, args.scene, seed, args.out)
        true_xy, true_h = true_trajectory(truth)
        true_poses = np.column_stack((true_xy, true_h))
        for row in measured_against_truth(info, true_poses, truth_walls(truth, true_xy)):
            measurement.append((seed,) + row)
        odometry = np.array([r[0] for r in info["jade_results"]], float)
        maps = {info["fusion"].PHASE_STEP_SIGMA_M: fused}  # as thrumapper-map makes it
        for sigma in (args.sigma_m, 0.0):
            if sigma not in maps:
                maps[sigma] = office_surveys.remapped(info, PHASE_STEP_SIGMA_M=sigma)
        for sigma in sorted(maps, reverse=True):
            adjustment.append((seed, sigma) + trajectory_figures(maps[sigma], true_xy, true_h, odometry))
        print(f"seed {seed} done", file=sys.stderr, flush=True)
    print(f"{args.scene}: the phase steps at the true poses against the truth's line-of-sight walls\n")
    print("| seed | wall (m) | steps | error median mm | error MAD mm | heading-rate error deg/m |")
    print("|---|---|---|---|---|---|")
    for seed, label, n, median, mad, rate in measurement:
        print(f"| {seed} | {label} | {n} | {median:+.2f} | {mad:.2f} | {rate:+.3f} |")
    print(f"\n{args.scene}: the adjustment with the phase steps (sigma > 0) and without (0)\n")
    print("| seed | PHASE_STEP_SIGMA_M | drift estimated / shown deg/m | trajectory RMS m | heading at end deg | "
          "cross / along at end m |")
    print("|---|---|---|---|---|---|")
    for seed, sigma, drift, realized, rms, end, cross, along in adjustment:
        drift = "–" if drift is None else f"{drift:.3f}"
        print(f"| {seed} | {sigma:g} | {drift} / {realized:.3f} | {rms:.3f} | {end:+.2f} | {cross:+.3f} / {along:+.3f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
