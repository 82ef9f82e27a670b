#!/usr/bin/python3
# SPDX-License-Identifier: GPL-3.0-or-later
"""The corridor alone: where its two walls are mapped, and where its CSI puts them when the two
are searched one at a time or together.

A corridor 2 m wide driven down its middle echoes from both walls with one delay. The scene
is office_floor with everything but the corridor and its end walls taken away
(scene_ablation.py's corridor_only: no rooms, doors or clutter). For each seed it:

1. simulates the survey and maps it as thrumapper-map does (the scene's odometry), and gives
   the line-of-sight RMS and where the mapped corridor walls' detections lie, in cm north of
   each face (the map turned back onto the true trajectory first, as map_rotation.py does:
   the turn about the first pose is another error);
2. gives the fusion's CSI refiner the true poses and the two true faces, shifted as each row
   of the second table says, and reports where the CSI puts each wall (cm north of its
   face) when it is searched alone, the other wall held where that map has it
   (CsiWallRefiner.material_offsets), and when the two are searched together
   (CsiWallRefiner.pair_offsets).

What it shows (docs/mapping.md, "The corridor alone: its two walls' one delay"): searched
alone, each wall follows where the other is mapped; together, the answer is the same from
every starting map.

Usage: benchmarks/corridor_pair.py [--seeds own 1] [--out /tmp/thrumapper_corridor_pair] [--jobs 2]
       (the module installed, or PYTHONPATH=build/test_modules; about a minute a seed on one core)
"""
import argparse
import contextlib
import io
import json
import os
import sys
from multiprocessing import Pool

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import office_surveys  # noqa: E402
from map_rotation import best_rotation  # noqa: E402
from scene_ablation import variant_scene  # noqa: E402

from gnuradio.thrumapper import evaluation, scene  # noqa: E402

#: the starting maps of the second table: (label, south face's shift, north face's shift), metres north
STARTS = (("the true faces", 0.0, 0.0),
          ("both 5 cm north", 0.05, 0.05),
          ("both 5 cm south", -0.05, -0.05),
          ("north wall 5 cm beyond its face", 0.0, 0.05),
          ("north wall 13 cm beyond its face", 0.0, 0.13))


def _face(y_m, x0_m, x1_m):
    """A wall dict for the face at y = y_m facing the corridor's axis (y = 0)."""
    normal = np.array([0.0, -np.sign(y_m)])
    return {"centre": np.array([(x0_m + x1_m) / 2.0, y_m]), "normal": normal,
            "direction": np.array([-normal[1], normal[0]]), "t0": -(x1_m - x0_m) / 2.0, "t1": (x1_m - x0_m) / 2.0}


def measure(job):
    seed, scene_yaml, out_root = job
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        fused, info, truth_path = office_surveys.mapped(scene_yaml, "office_floor", seed, out_root)
    geojson = os.path.join(out_root, f"office_floor-{seed}", "map.geojson")
    fused.write_geojson(geojson)
    scored = evaluation.score_map(geojson, truth_path)
    truth = evaluation.load_map(truth_path)
    # the map's detections turned back onto the true trajectory about its first pose
    origin = truth.trajectory[0, :2]
    angle = best_rotation(fused.trajectory[:, :2], truth.trajectory[:, :2], origin)
    c, s = np.cos(angle), np.sin(angle)
    points = fused.detections.get("line_of_sight", np.zeros((0, 2))) - origin
    points = np.column_stack([c * points[:, 0] - s * points[:, 1], s * points[:, 0] + c * points[:, 1]]) + origin
    along = (points[:, 0] > 0.0) & (points[:, 0] < 20.0)
    placed = {}
    for name, face_y in (("south", -1.0), ("north", 1.0)):
        near = along & (np.abs(points[:, 1] - face_y) < 0.35)
        placed[name] = float(np.mean(points[near, 1] - face_y)) if np.any(near) else None
    row = {"seed": seed, "los_m": scored["classes"]["line_of_sight"]["detections"].get("rms_m"),
           "turn_mrad": float(angle) * 1e3, "mapped_cm_north": placed, "starts": []}
    # the CSI with the true poses and the true faces, shifted
    refiner = info["fusion"].refiner
    poses = scene.load_scene(scene_yaml).poses
    for label, south_shift, north_shift in STARTS:
        walls = [_face(-1.0 + south_shift, -3.0, 23.0), _face(1.0 + north_shift, -3.0, 23.0)]
        refiner.set_map(walls, poses, [[] for _ in poses], [False, False])
        alone = [refiner.material_offsets(k, [refiner.material])[0] for k in (0, 1)]
        together = refiner.pair_offsets(0, 1)

        def north_of_face(k, offset):
            if offset is None:
                return None
            return float((walls[k]["centre"] + offset * walls[k]["normal"])[1] - (-1.0, 1.0)[k])

        row["starts"].append({"start": label,
                              "alone_cm_north": [north_of_face(k, alone[k]) for k in (0, 1)],
                              "together_cm_north": [None if together is None else north_of_face(k, together[k])
                                                    for k in (0, 1)]})
    return row


def _cm(value):
    return "   -  " if value is None else f"{100.0 * value:+6.1f}"


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter,
                                     epilog="\n\n".join(__doc__.split("\n\n")[1:]))
    parser.add_argument("--seeds", nargs="+", default=["own", "1"], help="seeds ('own': the scene's)")
    parser.add_argument("--out", default="/tmp/thrumapper_corridor_pair", help="where the surveys are kept")
    parser.add_argument("--jobs", type=int, default=2, help="surveys mapped at once")
    parser.add_argument("--json", action="store_true", help="print the rows as JSON lines as well")
    args = parser.parse_args(argv)
    if any(seed != "own" and not seed.isdigit() for seed in args.seeds):
        parser.error(f"--seeds: expected 'own' or whole numbers, got {' '.join(args.seeds)}")
    scene_yaml = variant_scene(os.path.join(office_surveys.SCENES_DIR, "office_floor.yaml"), "corridor_only", args.out)
    jobs = [(seed, scene_yaml, os.path.join(args.out, "corridor_only")) for seed in args.seeds]
    with Pool(max(1, args.jobs)) as pool:
        rows = pool.map(measure, jobs)
    print("The corridor alone, mapped as thrumapper-map maps it (detections cm north of each face, "
          "the map turned back onto the true trajectory)")
    print(f"{'seed':6s} {'line of sight':>14s} {'turn':>10s} {'south':>8s} {'north':>8s}")
    for row in rows:
        placed = row["mapped_cm_north"]
        print(f"{row['seed']:6s} {row['los_m']:12.3f} m {row['turn_mrad']:+7.1f} mrad "
              f"{_cm(placed['south']):>8s} {_cm(placed['north']):>8s}")
    print("\nThe CSI from the true poses: each face found alone (the other held) and together, cm north of it")
    print(f"{'seed':6s} {'starting map':34s} {'alone: south':>13s} {'north':>7s} {'together: south':>16s} {'north':>7s}")
    for row in rows:
        for start in row["starts"]:
            alone, together = start["alone_cm_north"], start["together_cm_north"]
            print(f"{row['seed']:6s} {start['start']:34s} {_cm(alone[0]):>13s} {_cm(alone[1]):>7s} "
                  f"{_cm(together[0]):>16s} {_cm(together[1]):>7s}")
    if args.json:
        for row in rows:
            print(json.dumps(row))
    return 0


if __name__ == "__main__":
    sys.exit(main())
