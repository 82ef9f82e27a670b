#!/usr/bin/python3
# SPDX-License-Identifier: GPL-3.0-or-later
"""Where the partitions behind a corridor wall are: their rooms' corners on the CSI.

A measurement, not a mapping step (docs/mapping.md, "Rooms from their corners"). The office
floors' partitions stand across the track: they give no specular echo, and they are most of
the hidden wall length the maps miss. But where a partition meets the exterior wall it makes
a concave dihedral, and a dihedral answers from its apex A over a wide aspect: its two
reflections make a point reflection through A, so every TX->RX element pair's path is
|T_k + R_m - 2A| long and the echo comes from A's bearing seen from the arrays' midpoint. On
the office floor (building_sim.path_truth) that echo is as strong as the exterior wall's own
specular echo (-72.6 against -73.5 dB at x = 2 m) and arrives 2.5 ns after it, 18 deg away.

For each hidden wall of a map (longer than 2 m), hypotheses A every 2.5 cm along its line,
out to 2 m past its ends, are scored on each pose's CSI with the map's walls and the direct
path projected out, the corridor wall crossed twice modelled by its insertion transmission
(CsiWallRefiner.room_corner_picks). The two faces of a partition are told apart by the side the
poses are on. Per pose the best hypothesis is kept when it captures 20 times what
white noise would; a corner shows as a run of poses whose best hypothesis stays put (a wall's
residue slides with the robot): at least 4 poses spanning 0.6 m of travel whose picks lie
within 0.25 m of their median, and whose picks move less than 0.25 m per metre of
travel (wall_fusion.corner_picks, runs_that_stay: the fusion's partitions use them too). Each such run is reported with its distance to the nearest true corner, and the
partitions they imply (the corner's line across to the line-of-sight wall in front, runs
within 0.5 m merged) are added to the map and scored: coverage and false wall length,
against the map without them.

Usage: benchmarks/room_corners.py [--scenes office_floor office_floor_drift] [--seeds own 1 2 3]
       [--out out/room_corners]   (PYTHONPATH=build/test_modules, or the module installed)
"""
import argparse
import contextlib
import copy
import importlib
import io
import os
import sys
import time

import numpy as np

from gnuradio.thrumapper import bistatic, cli_map, cli_sim, evaluation
from gnuradio.thrumapper.survey import read_survey
from gnuradio.thrumapper.wall_fusion import MapWall

wall_fusion = importlib.import_module("gnuradio.thrumapper.wall_fusion")  # (the package's name is the block)

HERE = os.path.dirname(os.path.abspath(__file__))
SCENES = os.path.join(HERE, "..", "examples", "scenes")
STEP_M = wall_fusion.CORNER_STEP_M
BEYOND_ENDS_M = 2.0
MERGE_M = 0.5


def corner_picks(refiner, wall, side, groups):
    """wall_fusion.corner_picks along a map's hidden wall (a MapWall), out to BEYOND_ENDS_M
    past its ends: rows (the arrays' midpoint's place along the wall, hypothesis t, J /
    noise)."""
    u = (wall.end_m - wall.start_m) / wall.length_m
    line = {"centre": wall.start_m, "normal": wall.normal, "direction": u}
    ts = np.arange(-BEYOND_ENDS_M, wall.length_m + BEYOND_ENDS_M, STEP_M)
    return wall_fusion.corner_picks(refiner, line, ts, groups, side)


def with_partitions(fused, corners):
    """A copy of the map with a hidden wall from each corner across to the line-of-sight wall
    parallel to its wall and in front of it (corners within MERGE_M of a stronger one merged)."""
    kept = []
    for point, wall, ratio in sorted(corners, key=lambda c: -c[2]):
        if all(np.hypot(*(point - q)) >= MERGE_M for q, _, _ in kept):
            kept.append((point, wall, ratio))
    out = copy.copy(fused)
    out.walls = list(fused.walls)
    for point, wall, _ in kept:
        reach = None
        for los in fused.walls:
            if los.cls != "line_of_sight" or float(los.normal @ wall.normal) < 0.95:
                continue
            ahead = float((point - los.start_m) @ los.normal)  # negative: behind its face
            if ahead < -0.3 and (reach is None or -ahead < reach):
                reach = -ahead
        if reach is not None:
            out.walls.append(MapWall(point.copy(), point + reach * wall.normal,
                                     np.array([-wall.normal[1], wall.normal[0]]), "hidden", 0.4, 0, 0, 0.0,
                                     source="partition"))
    return out, len(kept)


def survey_for(scene, seed, out):
    folder = os.path.join(out, f"{scene}-{seed}")
    meta = os.path.join(folder, f"{scene}.sigmf-meta")
    if not os.path.exists(meta):
        argv = [os.path.join(SCENES, scene + ".yaml"), "--out", folder, "--quiet"]
        if seed != "own":
            argv += ["--seed", str(seed)]
        with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
            if cli_sim.main(argv) != 0:
                raise RuntimeError(f"thrumapper-sim failed on {scene} seed {seed}")
    return folder, meta, os.path.join(folder, f"{scene}.truth.geojson")


def scores(fused, path, truth):
    fused.write_geojson(path, fused_detections=True)
    report = evaluation.score_map(evaluation.load_map(path), evaluation.load_map(truth))["classes"]
    los, hidden = report["line_of_sight"], report["hidden"]
    false = los["false_wall_length_m"] + hidden["false_wall_length_m"]
    return los["coverage"], hidden["coverage"], false / (los["truth_wall_length_m"] + hidden["truth_wall_length_m"])


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scenes", nargs="+", default=["office_floor", "office_floor_drift"])
    parser.add_argument("--seeds", nargs="+", default=["own", "1", "2", "3"])
    parser.add_argument("--out", default="out/room_corners")
    args = parser.parse_args(argv)
    for scene in args.scenes:
        for seed in args.seeds:
            started = time.perf_counter()
            folder, meta, truth = survey_for(scene, seed, args.out)
            fused, info = cli_map.map_survey(read_survey(meta), system_delay_s=31e-9)
            refiner = info["fusion"].refiner
            truth_corners = np.array([c["position"] for c in evaluation.load_map(truth).corners]).reshape(-1, 2)
            groups = sorted(refiner.poses)
            corners, errors = [], []
            for wall in fused.walls:
                if wall.cls != "hidden" or wall.length_m < 2.0:
                    continue
                u = (wall.end_m - wall.start_m) / wall.length_m
                for side in (1, -1):
                    for t, poses, travel, slope, ratio in wall_fusion.runs_that_stay(corner_picks(refiner, wall, side, groups)):
                        point = wall.start_m + t * u
                        error = float(np.hypot(*(truth_corners - point).T).min()) if truth_corners.size else float("nan")
                        corners.append((point, wall, ratio))
                        errors.append(error)
                        print(f"  {scene} {seed}: corner ({point[0]:.2f}, {point[1]:.2f}) on the hidden wall "
                              f"({wall.start_m[0]:.1f}, {wall.start_m[1]:.1f})-({wall.end_m[0]:.1f}, {wall.end_m[1]:.1f}), "
                              f"{poses} poses over {travel:.1f} m, slope {slope:+.2f}, {ratio:.0f} x noise; "
                              f"nearest true corner {error:.2f} m")
            drawn, count = with_partitions(fused, corners)
            before = scores(fused, os.path.join(folder, "map.geojson"), truth)
            after = scores(drawn, os.path.join(folder, "map-partitions.geojson"), truth)
            near = sum(1 for e in errors if e <= 0.3)
            print(f"{scene} seed {seed}: {len(corners)} corners ({near} within 0.3 m of a true one), {count} partitions; "
                  f"coverage LoS {before[0]:.1%} -> {after[0]:.1%}, hidden {before[1]:.1%} -> {after[1]:.1%}, "
                  f"false wall {before[2]:.1%} -> {after[2]:.1%} ({time.perf_counter() - started:.0f} s)", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
