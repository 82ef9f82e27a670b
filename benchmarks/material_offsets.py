#!/usr/bin/python3
# SPDX-License-Identifier: GPL-3.0-or-later
"""Where the CSI puts the office's exterior walls given their true material, from the true
map and the true poses: the material correction's offset (CsiWallRefiner.material_offsets)
by each way of combining the poses.

For each seed: simulates examples/scenes/office_floor.yaml (thrumapper-sim, reused under
OUT/), runs JADE as thrumapper-map does, gives the fusion's CSI refiner the true map and the
true poses (benchmarks/fit_bias.py's true_map: the corridor walls continuous faces, the rest
as the truth has them) and asks, for the north (concrete) and south (brick) exterior walls,
at what offset from their true face their material's echo explains the CSI best:
- "sum": the best offset of the summed J of up to MATERIAL_MAX_GROUPS poses spread along the
  wall (the default, MATERIAL_OFFSET_PER_POSE = False);
- "median": each of those poses' best offset alone, their median (True);
- "inliers": the summed J of the poses within MATERIAL_INLIER_M or 2.5 MADs of that median.
In cm, + toward the robot (in front of the face). With --poses, also each pose's own best
offset along the wall (every third pose), which shows where the sum is pulled.

docs/mapping.md, "A wall's material offset: the sum of its poses, or their median".

Usage: benchmarks/material_offsets.py [--seeds own 3 5] [--poses] [--out out/material_offsets]
       (PYTHONPATH=build/test_modules, or the module installed)
"""
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

import argparse  # noqa: E402
import json  # noqa: E402

import numpy as np  # noqa: E402
import yaml  # noqa: E402

from fit_bias import SCENE, jade_input, simulated, true_map  # noqa: E402  (this folder)
from gnuradio.thrumapper import scene as scene_module  # noqa: E402
from gnuradio.thrumapper.wall_fusion import FusionSettings, RadarGeometry, WallFusion  # noqa: E402
from gnuradio.thrumapper.wall_refinement import CsiWallRefiner  # noqa: E402

MODES = (("sum", False), ("median", True), ("inliers", "inliers"))
EXTERIOR = {"exterior_north": "concrete", "exterior_south": "brick"}


def refiner_on_truth(meta, truth_path, scene):
    """The fusion's CSI refiner of this survey, handed the true map and poses; the true map's
    walls; the true poses."""
    survey, items, system_delay_s = jade_input(meta)
    fusion = WallFusion(RadarGeometry.from_survey(survey), FusionSettings())
    fusion.enable_csi_refinement(system_delay_s)
    for item in items:
        fusion.add(*item)
    with open(truth_path, encoding="utf-8") as handle:
        truth = json.load(handle)
    trajectory = next(f for f in truth["features"] if f["properties"].get("kind") == "trajectory")
    poses = np.column_stack([np.asarray(trajectory["geometry"]["coordinates"], float),
                             trajectory["properties"]["headings_rad"]])
    walls, hidden = true_map(truth, scene)
    refiner = fusion.refiner
    refiner.set_map(walls, poses, [[(q["aoa_rad"], q["delay_s"]) for q in g.paths] for g in fusion.groups], hidden)
    return refiner, walls, poses


def exterior_walls(walls, scene):
    """{name: index in walls} of the exterior walls' faces toward the track."""
    centre_y = {w["name"]: float(np.mean(np.asarray(w["segment"], float)[:, 1])) for w in scene["walls"]}
    out = {}
    for name in EXTERIOR:
        for k, w in enumerate(walls):
            # the face nearer the track, of the wall on that centre line
            if abs(w["normal"][1]) > 0.99 and abs(float(w["centre"][1]) - centre_y[name]) < 0.2 and \
                    float(w["normal"][1]) * centre_y[name] < 0:
                out[name] = k
    return out


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     epilog=__doc__.split("\n\n", 1)[1],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seeds", nargs="+", default=["own", "3", "5"],
                        help="thrumapper-sim seeds ('own': the scene's); default %(default)s")
    parser.add_argument("--poses", action="store_true", help="also each pose's own best offset along the walls")
    parser.add_argument("--out", default="out/material_offsets", help="where the surveys are kept and reused")
    args = parser.parse_args(argv)
    with open(SCENE, encoding="utf-8") as handle:
        scene = yaml.safe_load(handle)
    saved = CsiWallRefiner.MATERIAL_OFFSET_PER_POSE
    print("| seed | wall | " + " | ".join(name for name, _ in MODES) + " |")
    print("|---|---|" + "---|" * len(MODES))
    try:
        for seed in args.seeds:
            own = seed == "own"
            meta, truth = simulated(scene, os.path.join(args.out, "own" if own else f"seed-{seed}"),
                                    None if own else int(seed))
            refiner, walls, poses = refiner_on_truth(meta, truth, scene)
            for name, k in exterior_walls(walls, scene).items():
                material = scene_module.MATERIAL_PRESETS[EXTERIOR[name]]
                cells = []
                for _, mode in MODES:
                    CsiWallRefiner.MATERIAL_OFFSET_PER_POSE = mode
                    offset, = refiner.material_offsets(k, [material])
                    cells.append("none" if offset is None else f"{100 * offset:+.1f}")
                print(f"| {seed} | {name} ({EXTERIOR[name]}) | " + " | ".join(cells) + " |", flush=True)
                if args.poses:
                    groups = [g for g in range(0, len(poses), 3) if refiner.sees(g, k)]
                    row = [f"{poses[g, 0]:.1f} m: " + ("none" if offset is None else f"{100 * offset:+.0f}")
                           for g, offset in zip(groups, refiner.pose_material_offsets(k, groups, material))]
                    print(f"|   | each pose, x: cm | {'; '.join(row)} |", flush=True)
    finally:
        CsiWallRefiner.MATERIAL_OFFSET_PER_POSE = saved
    return 0


if __name__ == "__main__":
    sys.exit(main())
