#!/usr/bin/python3
# SPDX-License-Identifier: GPL-3.0-or-later
"""How well a corridor survey's trajectory can be known at all: a linear-Gaussian model of
the office scenes' survey (docs/mapping.md, "Where the office floors' error comes from").

The robot drives P poses STEP metres apart down a straight corridor; the first pose is known
(the map's frame is tied to it). Its wheel odometry reports each step's heading change with
white noise (SIGMA_H per step, the scene's heading_noise_deg) on top of an unknown constant
drift per metre, and each step's sideways motion with white noise (SIGMA_Y). From every pose
the two corridor walls (straight lines, offset and slope unknown) are measured: the distance
with white noise (SIGMA_W) plus, optionally, runs of bias correlated over RUN_M metres
(SIGMA_RUN, exponential correlation), and the orientation (SIGMA_O). Nothing else fixes the
map's rotation about the first pose but the first steps' odometry, which is what makes the
cross-track error grow along the track even with perfect walls.

Prints, for each case, the distribution of the trajectory's RMS cross-track error over
surveys (median, 90th percentile, the share above the issue's 0.10 m): for the best linear
estimator that knows the error statistics (generalised least squares), and for one that
weights like WallFusion's pose adjustment (the fits taken as white, csi_point_sigma_m 3 cm,
csi_orientation_sigma_deg 2 deg, odometry_heading_sigma_deg 0.05 deg per step).

Usage: benchmarks/trajectory_bound.py [--poses 100] [--step-m 0.2] [--heading-noise-deg 0.1]
"""
import argparse

import numpy as np


def design(poses, step_m, walls=2):
    """Rows of the linear model (unknowns: y and heading of poses 1.., drift, each wall's
    offset and slope) and what each row measures."""
    n = poses - 1
    unknowns = 2 * n + 1 + 2 * walls
    rows, kinds = [], []

    def row(entries):
        v = np.zeros(unknowns)
        for k, x in entries:
            v[k] += x
        return v

    def y(i):
        return [] if i == 0 else [(i - 1, 1.0)]

    def heading(i):
        return [] if i == 0 else [(n + i - 1, 1.0)]

    drift = 2 * n
    for i in range(1, poses):
        rows.append(row(heading(i) + [(k, -x) for k, x in heading(i - 1)] + [(drift, -step_m)]))
        kinds.append(("heading", None, i))
        rows.append(row(y(i) + [(k, -x) for k, x in y(i - 1)] + [(k, -step_m * x) for k, x in heading(i - 1)]))
        kinds.append(("side", None, i))
    x = np.arange(poses) * step_m
    for w in range(walls):
        offset, slope = 2 * n + 1 + 2 * w, 2 * n + 2 + 2 * w
        for i in range(poses):
            rows.append(row([(offset, 1.0), (slope, x[i])] + [(k, -v) for k, v in y(i)]))
            kinds.append(("distance", w, i))
        for i in range(poses):
            rows.append(row([(slope, 1.0)] + [(k, -v) for k, v in heading(i)]))
            kinds.append(("orientation", w, i))
    return np.array(rows), kinds, n, x


def covariance(kinds, x, sigma_h_deg, sigma_y_m, sigma_w_m, sigma_run_m, run_m, sigma_o_deg):
    """The measurements' covariance."""
    cov = np.zeros((len(kinds), len(kinds)))
    distances = {}
    for j, (kind, wall, i) in enumerate(kinds):
        if kind == "heading":
            cov[j, j] = np.radians(sigma_h_deg) ** 2
        elif kind == "side":
            cov[j, j] = sigma_y_m ** 2
        elif kind == "orientation":
            cov[j, j] = np.radians(sigma_o_deg) ** 2
        else:
            distances.setdefault(wall, []).append((j, i))
    for members in distances.values():
        rows = np.array([j for j, _ in members])
        along = x[[i for _, i in members]]
        cov[np.ix_(rows, rows)] = sigma_w_m ** 2 * np.eye(rows.size) + \
            sigma_run_m ** 2 * np.exp(-np.abs(along[:, None] - along[None, :]) / run_m)
    return cov


def trajectory_rms(a, n, true_cov, weight_cov, surveys, rng):
    """RMS cross-track error per simulated survey of the estimator weighting by weight_cov."""
    w = np.linalg.inv(weight_cov)
    gain = np.linalg.pinv(a.T @ w @ a) @ a.T @ w
    cov = (gain @ true_cov @ gain.T)[:n, :n]
    errors = rng.standard_normal((surveys, n)) @ np.linalg.cholesky(cov + 1e-14 * np.eye(n)).T
    return np.sqrt(np.sum(errors ** 2, axis=1) / (n + 1))  # the first pose is exact


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--poses", type=int, default=100)
    p.add_argument("--step-m", type=float, default=0.2)
    p.add_argument("--heading-noise-deg", type=float, default=0.1, help="odometry heading noise per step")
    p.add_argument("--side-noise-m", type=float, default=0.003, help="odometry sideways noise per step")
    p.add_argument("--surveys", type=int, default=20000, help="simulated surveys per case")
    args = p.parse_args(argv)
    a, kinds, n, x = design(args.poses, args.step_m)
    rng = np.random.default_rng(7)
    adjustment = covariance(kinds, x, 0.05, 0.002, 0.03, 0.0, 1.0, 2.0)
    print("wall fits: white / runs (over 2 m) | estimator | trajectory RMS median, 90th pct, share > 0.10 m")
    for white_m, run_sd_m in ((0.01, 0.0), (0.03, 0.0), (0.03, 0.05), (0.03, 0.08)):
        true = covariance(kinds, x, args.heading_noise_deg, args.side_noise_m, white_m, run_sd_m, 2.0, 2.0)
        for label, weights in (("best linear", true), ("adjustment's weights", adjustment)):
            rms = trajectory_rms(a, n, true, weights, args.surveys, rng)
            print(f"{white_m * 100:4.0f} cm / {run_sd_m * 100:2.0f} cm | {label:20s} | {np.median(rms) * 100:5.1f} cm "
                  f"{np.percentile(rms, 90) * 100:5.1f} cm {np.mean(rms > 0.10) * 100:4.0f} %")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
