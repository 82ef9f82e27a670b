#!/usr/bin/python3
# SPDX-License-Identifier: GPL-3.0-or-later
"""Which part of skewed_walls biases the CSI echo fit of its 18° wall.

benchmarks/fit_bias.py's measurement on the other example scene: examples/scenes/skewed_walls.yaml
and variants of it with one part of the scene taken away, each:

1. simulated (thrumapper-sim, --quiet) into OUT/SEED/VARIANT/ (reused while the variant's scene,
   written there, is unchanged);
2. RX-calibrated and run through JADE on every pose group as thrumapper-map does, with the
   survey's own system delay (this scene states it);
3. given to a WallFusion's CsiWallRefiner with the TRUE map (each wall of the truth one face,
   pieces merged; the 15° wall hidden) and the TRUE poses; the survey states no wall model, so
   the refiner models every wall as the fusion does then: plasterboard;
4. the 18° wall fitted at every pose whose specular point lies on its face
   (CsiWallRefiner.fit_echo's search), and each fit's offset along the wall's normal (cm, +
   toward the robot) and turn (degrees, + counter-clockwise: above 18°) printed.

Per variant: the poses fitted, offset RMS / mean, turn mean, the same over the brick wall's
stretch (x >= 6 m), the fits stopped at the search bound, and the longest run of consecutive
poses more than 3 cm off on one side (poses, x range, mean).

Variants (--variants, comma-separated; default all):
  full                    the scene as it is
  no_clutter              no cabinet, no desk
  no_12deg                without the 12° plasterboard wall
  no_brick                without the brick wall
  no_hidden               without the hidden 15° wall
  only_18deg              the 18° wall alone
  first_order             first-order paths only (physics: second_order off)
  brick_as_plasterboard   the brick wall built of plasterboard (the model's material)

--doubles models the double bounces between facing line-of-sight walls in the fits
(CsiWallRefiner.DOUBLE_BOUNCES, "coherent" or "free_gain"). Measured and what it shows:
docs/mapping.md, "What biases the 18° wall's fits".

Usage: benchmarks/fit_bias_skewed.py [--out DIR] [--seed N] [--variants full,no_brick,...]
                                     [--doubles [coherent|free_gain]]
       (PYTHONPATH=build/test_modules, or the module installed)
"""
import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse  # noqa: E402
import copy  # noqa: E402
import json  # noqa: E402
import math  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402
import yaml  # noqa: E402

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
import fit_bias  # noqa: E402  (simulated, jade_input, face)

from gnuradio.thrumapper.wall_fusion import FusionSettings, RadarGeometry, WallFusion  # noqa: E402

SCENE = os.path.join(HERE, "..", "examples", "scenes", "skewed_walls.yaml")
TARGET = "skew_left_18deg"
HIDDEN = ("hidden_skew_15deg",)
BRICK_STRETCH_X_M = 6.0  # the brick wall runs from x = 6 m, across the track
RUN_CM = 3.0


def _without(name):
    def change(scene):
        scene["walls"] = [w for w in scene["walls"] if w["name"] != name]
    return change


def _only_target(scene):
    scene["walls"] = [w for w in scene["walls"] if w["name"] == TARGET]
    scene.pop("clutter", None)


def _first_order(scene):
    scene.setdefault("physics", {})["second_order"] = False


def _brick_as_plasterboard(scene):
    for w in scene["walls"]:
        if w.get("material") == "brick":
            w["material"] = "plasterboard"


VARIANTS = {
    "full": lambda scene: None,
    "no_clutter": lambda scene: scene.pop("clutter", None),
    "no_12deg": _without("skew_right_12deg"),
    "no_brick": _without("brick_right"),
    "no_hidden": _without("hidden_skew_15deg"),
    "only_18deg": _only_target,
    "first_order": _first_order,
    "brick_as_plasterboard": _brick_as_plasterboard,
}


def true_map(truth, scene):
    """(walls, hidden, names): each scene wall's face toward the track (its pieces merged) as one
    refiner wall, in the scene's order."""
    centre_lines = {w["name"]: np.asarray(w["segment"], float) for w in scene["walls"]}
    points = {}
    for f in truth["features"]:
        p = f["properties"]
        if p.get("kind") == "wall" and not p.get("door"):
            points.setdefault(p["name"], []).extend(f["geometry"]["coordinates"])
    walls, hidden, names = [], [], []
    for name, (start, end) in centre_lines.items():
        if name not in points:
            continue
        d = (end - start) / np.hypot(*(end - start))
        n = np.array([-d[1], d[0]])
        pts = np.asarray(points[name], float)
        if float((pts[0] - start) @ n) < 0:  # the face lies on the normal's side of the centre line
            n = -n
        along = pts @ d
        walls.append(fit_bias.face(pts[np.argmin(along)], pts[np.argmax(along)], n))
        hidden.append(name in HIDDEN)
        names.append(name)
    return walls, hidden, names


def fits(survey, items, delay_s, truth_path, scene, doubles):
    """[(pose x, offset cm, turn deg, at the search bound)] of the 18° wall, pose by pose."""
    with open(truth_path, encoding="utf-8") as handle:
        truth = json.load(handle)
    fusion = WallFusion(RadarGeometry.from_survey(survey), FusionSettings())
    fusion.enable_csi_refinement(delay_s)
    for item in items:
        fusion.add(*item)
    track = next(f for f in truth["features"] if f["properties"].get("kind") == "trajectory")
    poses = np.column_stack([np.asarray(track["geometry"]["coordinates"], float), track["properties"]["headings_rad"]])
    walls, hidden, names = true_map(truth, scene)
    refiner = fusion.refiner
    refiner.DOUBLE_BOUNCES = doubles or False
    refiner.set_map(walls, poses, [[(q["aoa_rad"], q["delay_s"]) for q in g.paths] for g in fusion.groups], hidden)
    k = names.index(TARGET)
    wall, s = walls[k], refiner.settings
    out = []
    for g, pose in enumerate(poses):
        if not refiner.sees(g, k):
            continue
        pivot = refiner._pivot(wall, pose)
        if not wall["t0"] <= float((pivot - wall["centre"]) @ wall["direction"]) <= wall["t1"]:
            continue  # the specular point past the wall's end: nothing to fit there
        offset_m, turn_rad, _ = refiner._fit(k, [g], pivot, 0.04, 1.0)  # fit_echo's search
        bound = abs(offset_m) >= s.max_offset_m - 1e-3 or abs(math.degrees(turn_rad)) >= s.max_rotation_deg - 0.05
        out.append((float(pose[0]), 100.0 * offset_m, math.degrees(turn_rad), bool(bound)))
    return out


def longest_run(rows):
    """(poses, first x, last x, mean cm) of the longest run over RUN_CM of one sign."""
    best, run, side = (0, 0.0, 0.0, 0.0), [], 0
    for row in rows + [None]:
        sign = 0 if row is None or abs(row[1]) <= RUN_CM else (1 if row[1] > 0 else -1)
        if sign and sign == side:
            run.append(row)
            continue
        if len(run) > best[0]:
            best = (len(run), run[0][0], run[-1][0], float(np.mean([r[1] for r in run])))
        run, side = ([row] if sign else []), sign
    return best


def cells(rows):
    if not rows:
        return "0 | – | – | – | – | – | –"
    offset = np.array([r[1] for r in rows])
    turn = np.array([r[2] for r in rows])
    brick = np.array([r[0] >= BRICK_STRETCH_X_M for r in rows])
    n, x0, x1, mean = longest_run(rows)
    run = f"{n} poses, x {x0:.1f}–{x1:.1f} m ({mean:+.0f})" if n else "–"
    stretch = "–"
    if brick.any():
        stretch = (f"{math.sqrt(np.mean(offset[brick] ** 2)):.1f} / {offset[brick].mean():+.1f}, "
                   f"{turn[brick].mean():+.2f}°")
    return (f"{len(rows)} | {math.sqrt(np.mean(offset ** 2)):.1f} / {offset.mean():+.1f} | {turn.mean():+.2f} | "
            f"{stretch} | {sum(r[3] for r in rows)} | {run}")


def main(argv=None):
    parser = argparse.ArgumentParser(
        description=__doc__.splitlines()[0],
        epilog="Each variant takes about 10 s (the survey reused from --out when unchanged).")
    parser.add_argument("--out", default="out/fit_bias_skewed", help="where the simulated surveys are kept")
    parser.add_argument("--seed", type=int, default=None, help="simulator seed (default: the scene's own)")
    parser.add_argument("--variants", default=",".join(VARIANTS),
                        help=f"comma-separated, of: {', '.join(VARIANTS)} (default: all)")
    parser.add_argument("--doubles", nargs="?", const="coherent", default=None, choices=("coherent", "free_gain"),
                        help="model the double bounces between facing walls in the fits (default mode: coherent)")
    args = parser.parse_args(argv)
    names = [v.strip() for v in args.variants.split(",") if v.strip()]
    unknown = [v for v in names if v not in VARIANTS]
    if unknown:
        parser.error(f"unknown variants {unknown}; known: {', '.join(VARIANTS)}")
    with open(SCENE, encoding="utf-8") as handle:
        base = yaml.safe_load(handle)
    root = os.path.join(args.out, "own" if args.seed is None else f"seed-{args.seed}")
    model = f", doubles {args.doubles}" if args.doubles else ""
    lines = []
    for name in names:
        started = time.perf_counter()
        try:
            scene = copy.deepcopy(base)
            VARIANTS[name](scene)
            meta, truth = fit_bias.simulated(scene, os.path.join(root, name), args.seed)
            survey, items, delay_s = fit_bias.jade_input(meta, system_delay_s=None)  # the survey's delay
            lines.append(f"| {name} | {cells(fits(survey, items, delay_s, truth, scene, args.doubles))} |")
        except Exception as error:  # one variant's failure is reported, the rest go on
            print(f"fit_bias_skewed: {name} failed: {type(error).__name__}: {error}", file=sys.stderr)
            lines.append(f"| {name} | failed |")
        print(f"{name}: {time.perf_counter() - started:.0f} s", file=sys.stderr, flush=True)
    print(f"skewed_walls, seed {'own' if args.seed is None else args.seed}: the 18° wall fitted pose by pose on "
          f"the true map from the true poses{model}; offset cm (+ toward the robot), turn deg (+ counter-clockwise)")
    print("| variant | poses | offset RMS / mean | turn mean | x >= 6 m: offset RMS / mean, turn | at the bound | "
          "longest run > 3 cm |")
    print("| --- | --- | --- | --- | --- | --- | --- |")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
