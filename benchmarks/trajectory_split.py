#!/usr/bin/python3
# SPDX-License-Identifier: GPL-3.0-or-later
"""Where a map's trajectory error lies: along the track or across it.

For each map and its truth (thrumapper-eval's files; the two trajectories hold one pose for
one), the RMS of the map's poses against the truth's along the track (the truth's first-to-last
direction) and across it, the same along the track for the odometry the map was made from (the
map's "odometry" feature), the map's along-track scale against the truth's (the least-squares
slope of its distance from the first pose on the truth's), and what the trajectory RMS would be
with the odometry's along-track positions put in instead of the map's: as they are, and scaled
by the truth's own ratio to them (an oracle: the scale the odometry needed), the map's
cross-track positions kept. A straight track is assumed (the office surveys'); on a track that
turns, "along" and "across" are those of its chord.

docs/mapping.md, "The trajectories' error is along the track".

Usage: benchmarks/trajectory_split.py MAP.geojson TRUTH.geojson [MAP TRUTH ...]
       (PYTHONPATH=build/test_modules, or the module installed)
"""
import json
import os
import sys

import numpy as np

from map_rotation import pair_files, trajectory_pairs  # (this folder)


def odometry_of(map_path):
    """(P, 2) the map GeoJSON's odometry positions, or None when it has none."""
    with open(map_path) as f:
        features = json.load(f).get("features", [])
    for feature in features:
        if feature.get("properties", {}).get("kind") == "odometry":
            return np.asarray(feature["geometry"]["coordinates"], float).reshape(-1, 2)
    return None


def split(ours, true, odometry=None):
    """dict of the along / across RMS (m) of `ours` (P, 2) against `true` (P, 2), the map's
    along-track scale, and with `odometry` (P, 2) its along RMS and the two substitutions."""
    u = true[-1] - true[0]
    if not np.hypot(*u) > 0:
        raise ValueError("the truth's trajectory does not move: no direction to split along")
    u = u / np.hypot(*u)
    v = np.array([-u[1], u[0]])
    t_true, t_ours = (true - true[0]) @ u, (ours - true[0]) @ u
    along = t_ours - t_true
    across = (ours - true) @ v
    out = {"along_m": float(np.sqrt(np.mean(along ** 2))), "across_m": float(np.sqrt(np.mean(across ** 2))),
           "scale": float(np.polyfit(t_true, t_ours - t_ours[0], 1)[0])}
    out["total_m"] = float(np.hypot(out["along_m"], out["across_m"]))
    if odometry is not None and len(odometry) == len(true):
        t_odo = (odometry - true[0]) @ u
        rms = lambda e: float(np.sqrt(np.mean(e ** 2)))  # noqa: E731
        out["odometry_along_m"] = rms(t_odo - t_true)
        out["with_odometry_along_m"] = float(np.hypot(out["odometry_along_m"], out["across_m"]))
        needed = float(np.polyfit(t_odo - t_odo[0], t_true - t_true[0], 1)[0])
        scaled = t_odo[0] + needed * (t_odo - t_odo[0])
        out["with_true_scale_m"] = float(np.hypot(rms(scaled - t_true), out["across_m"]))
    return out


def main(argv=None):
    pairs = trajectory_pairs(pair_files(argv, __doc__, "trajectory_split.py"), "trajectory_split.py")
    if pairs is None:
        return 2
    columns = ("total_m", "along_m", "across_m", "scale", "odometry_along_m", "with_odometry_along_m",
               "with_true_scale_m")
    print(f"{'map':34s} {'RMS':>6s} {'along':>6s} {'across':>6s} {'scale':>7s} {'odo.':>6s} {'w.odo':>6s} {'w.true':>6s}")
    rows = []
    for map_path, truth_path, ours, truth in pairs:
        try:
            row = split(np.asarray(ours.trajectory, float)[:, :2], np.asarray(truth.trajectory, float)[:, :2],
                        odometry_of(map_path))
        except ValueError as error:
            print(f"{truth_path}: {error}", file=sys.stderr)
            return 2
        rows.append(row)
        name = os.path.basename(os.path.dirname(os.path.abspath(map_path))) + "/" + os.path.basename(map_path)
        print(f"{name[-34:]:34s} " + " ".join(
            ("   –  " if row.get(k) is None else (f"{row[k]:7.4f}" if k == "scale" else f"{row[k]:6.3f}"))
            for k in columns))
    if len(rows) > 1:
        for k in columns:
            values = [r[k] for r in rows if r.get(k) is not None]
            if values:
                within = sum(v <= 0.10 for v in values) if k in ("total_m", "with_odometry_along_m", "with_true_scale_m") else None
                print(f"{k}: median {np.median(values):.4f}, mean {np.mean(values):.4f}"
                      + ("" if within is None else f", within 0.10 m: {within} of {len(values)}"))
    return 0


if __name__ == "__main__":
    sys.exit(main())
