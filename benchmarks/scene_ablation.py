#!/usr/bin/python3
# SPDX-License-Identifier: GPL-3.0-or-later
"""The whole chain on an example scene with one of its elements taken away.

Each variant is the scene less one thing: its clutter, its doors, its partitions, everything
but the corridor, one kind of the simulator's physics (second-order paths, edge scatter,
the diffuse scatterers along every face), or the TX chains' errors (no_tx_errors: the
per-element gain, phase and delay errors, which leave the direct path's leak in the null; what
a TX calibration would take away). One variant adds instead: tx_calibrated, the radio's TX
calibration before the survey (impairments.tx_calibration_frames: 4, tx_calibration.py), which
measures those errors and sends the survey with corrected weights. Each is simulated on the given seeds, mapped as
thrumapper-map maps it, and scored with thrumapper-eval against its own truth. The table gives
the medians over the seeds: line of sight and hidden detection error, the trajectory error,
the turn of the whole map about its first pose (benchmarks/map_rotation.py) and the error of
the odometry drift the adjustment estimates (against the drift the odometry's headings show:
its last heading less the truth's, over the path). LoS* and hid* are the classes' RMS without
their detections on a true wall of the other class: where the walls are put, apart from the
class decisions, which flip between surveys whose data differ by very little.

With --poses truth the fusion is given the true poses as its odometry (its pose correction
still runs, and may move them); with --poses truth-held it keeps them (no pose correction).
What is left is the map's own error, what the poses cannot be blamed for.

With --sources N, each variant's N largest sources of detection error per class follow the
table, pooled over the seeds (thrumapper-eval's "error_sources": detections more than 0.3 m
from every true wall of their class, on a true wall of the other class or near none, by
wall), as shares of the class's squared error summed over the seeds: the RMS over many
surveys is often a few detections on one wall.

A mapper that understood the scene would map every variant at least as well as the whole
scene; where a variant maps worse, the mapper leans on what was taken away, or a decision of
its (a class, a doorway, a side wall) flips without it (docs/mapping.md, "The whole chain
without one element of the scene").

Usage: benchmarks/scene_ablation.py [--scene office_floor] [--seeds own 1 2 3]
           [--variants full no_clutter ...] [--poses odometry|truth|truth-held]
           [--out /tmp/thrumapper_ablation] [--jobs 2] [--sources 3]
       (PYTHONPATH=build/test_modules, or the module installed; about 15 s a survey a core)
A variant that takes nothing away from the scene (no_doors on a scene without doors), or
leaves it without a wall, is refused with a message naming it.
"""
import argparse
import contextlib
import copy
import io
import json
import math
import os
import sys
from multiprocessing import Pool

import numpy as np
import yaml

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import office_surveys  # noqa: E402
from map_rotation import best_rotation  # noqa: E402

from gnuradio.thrumapper import evaluation  # noqa: E402


def _without(key):
    def change(data):
        data.pop(key, None)
    return change


def _physics_off(key):
    def change(data):
        data.setdefault("physics", {})[key] = False
    return change


def _corridor_only(data):
    data.pop("clutter", None)
    data.pop("doors", None)
    data["walls"] = [w for w in data["walls"] if w["name"].startswith(("corridor", "end"))]


def _no_partitions(data):
    data["walls"] = [w for w in data["walls"] if not w["name"].startswith("partition")]
    # doors stay where their walls stay
    names = {w["name"] for w in data["walls"]}
    if "doors" in data:
        data["doors"] = [d for d in data["doors"] if d["wall"] in names]


def _no_tx_errors(data):
    tx = (data.get("impairments") or {}).get("tx")
    if tx:
        data["impairments"]["tx"] = {k: (0.0 if isinstance(v, (int, float)) else v) for k, v in tx.items()}


def _tx_calibrated(data):
    # The radio's TX calibration before the survey (tx_calibration.py): 4 frames per element
    # at each of the first 4 poses; the survey frames go out with the corrected weights.
    if not any((data.get("impairments") or {}).get("tx", {}).values()):
        return  # nothing to calibrate: refused as taking nothing away
    data["impairments"]["tx_calibration_frames"] = 4


VARIANTS = {
    "full": lambda data: None,
    "no_clutter": _without("clutter"),
    "no_doors": _without("doors"),
    "no_partitions": _no_partitions,
    "corridor_only": _corridor_only,
    "no_second_order": _physics_off("second_order"),
    "no_edges": _physics_off("edges"),
    "no_diffuse": _physics_off("diffuse"),
    "no_tx_errors": _no_tx_errors,
    "tx_calibrated": _tx_calibrated,
}


class VariantError(ValueError):
    """A variant that does not apply to the scene (it would change nothing, or leave no wall)."""


def variant_scene(scene_yaml, variant, out_root):
    """The scene with `variant` applied, written as out_root/VARIANT/SCENE.yaml; its path.
    Raises VariantError where the variant takes nothing away or leaves no wall."""
    with open(scene_yaml, encoding="utf-8") as handle:
        original = yaml.safe_load(handle)
    data = copy.deepcopy(original)
    VARIANTS[variant](data)
    if variant != "full" and data == original:
        raise VariantError(f"{variant} takes nothing away from {os.path.basename(scene_yaml)}")
    if not data.get("walls"):
        raise VariantError(f"{variant} leaves {os.path.basename(scene_yaml)} without a wall")
    folder = os.path.join(out_root, variant)
    os.makedirs(folder, exist_ok=True)
    path = os.path.join(folder, os.path.basename(scene_yaml))
    with open(path, "w", encoding="utf-8") as handle:
        yaml.safe_dump(data, handle)
    return path


def _trajectory(geojson):
    for feature in geojson["features"]:
        props = feature.get("properties") or {}
        if props.get("kind") == "trajectory":
            xy = np.asarray(feature["geometry"]["coordinates"], float)
            h = props.get("headings_rad")
            return xy, (np.zeros(len(xy)) if h is None else np.asarray(h, float))
    return None, None


#: --poses: what the fusion is given as the odometry, and whether it corrects it
POSES = {"odometry": ("odometry", True), "truth": ("truth", True), "truth-held": ("truth", False)}


def score(job):
    """Map one (variant, seed) and score it: a dict of numbers."""
    scene, variant, seed, scene_yaml, out_root, poses = job
    source, corrected = POSES[poses]
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        # from the true poses the odometry's map is not needed: JADE only, mapped below
        fused, info, truth_path = office_surveys.mapped(scene_yaml, scene, seed, os.path.join(out_root, variant),
                                                        build=source == "odometry")
    with open(truth_path, encoding="utf-8") as handle:
        true_xy, true_h = _trajectory(json.load(handle))
    odometry = np.asarray([r[0] for r in info["jade_results"]], float)
    if source == "truth":
        if true_xy is None or len(true_xy) != len(odometry):
            raise RuntimeError(f"{truth_path}: {0 if true_xy is None else len(true_xy)} true poses for "
                               f"{len(odometry)} pose groups in the survey")
        odometry = np.column_stack((true_xy, true_h))
        with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
            fused = office_surveys.remapped(info, odometry, settings={"correct_poses": corrected})
    map_path = os.path.join(out_root, variant, f"{scene}-{seed}", f"map-{poses}.geojson")
    fused.write_geojson(map_path, fused_detections=True)
    scores = evaluation.score_map(map_path, truth_path)
    with open(map_path, encoding="utf-8") as handle:
        ours, _ = _trajectory(json.load(handle))
    turn = math.degrees(best_rotation(ours, true_xy, true_xy[0])) if ours is not None else None
    path_m = float(np.sum(np.hypot(*np.diff(true_xy, axis=0).T)))
    true_drift = math.degrees(math.remainder((odometry[-1, 2] - odometry[0, 2]) - (true_h[-1] - true_h[0]),
                                             2.0 * math.pi)) / path_m
    classes = scores["classes"]
    squared = {}  # the class's summed squared error, and that of each error source
    for cls in evaluation.CLASSES:
        d = classes[cls]["detections"]
        total = (d["rms_m"] or 0.0) ** 2 * d["count"]
        squared[cls] = {"total": total, "sources": [
            {"why": e["why"], "wall": e["wall"], "count": e["count"], "squared_m2": e["share"] * total}
            for e in d.get("error_sources", [])]}
    def same_class(cls):
        # the class's RMS without its detections on a true wall of the other class: the
        # walls' placement, apart from the class decisions that flip (a few detections
        # that move the RMS by decimetres between surveys whose data differ by -48 dB)
        d = classes[cls]["detections"]
        if d["rms_m"] is None:
            return None
        flipped = sum(e["share"] for e in d.get("error_sources", []) if e["why"] == "other_class")
        return d["rms_m"] * math.sqrt(max(0.0, 1.0 - flipped))

    return {"variant": variant, "seed": seed, "poses": poses,
            "los_m": classes["line_of_sight"]["detections"]["rms_m"],
            "hidden_m": classes["hidden"]["detections"]["rms_m"],
            "los_same_class_m": same_class("line_of_sight"),
            "hidden_same_class_m": same_class("hidden"),
            "los_coverage": classes["line_of_sight"]["coverage"],
            "hidden_coverage": classes["hidden"]["coverage"],
            "trajectory_m": (scores["trajectory"] or {}).get("rms_m"),
            "turn_deg": turn,
            "drift_error_deg_per_m": fused.stats.get("odometry_drift_deg_per_m", 0.0) - true_drift,
            "squared_error": squared}


def pooled_sources(rows, cls):
    """The error sources of one class over rows (score's), as (share of the summed squared
    error, why, wall, detections), largest first."""
    total = sum(r["squared_error"][cls]["total"] for r in rows)
    pooled = {}
    for r in rows:
        for e in r["squared_error"][cls]["sources"]:
            key = (e["why"], e["wall"])
            value, count = pooled.get(key, (0.0, 0))
            pooled[key] = (value + e["squared_m2"], count + e["count"])
    if total <= 0.0:
        return []
    return sorted(((v / total, why, wall, n) for (why, wall), (v, n) in pooled.items()), reverse=True)


def _median(rows, key, absolute=False):
    values = [abs(r[key]) if absolute else r[key] for r in rows if r[key] is not None]
    return float(np.median(values)) if values else None


def main(argv=None):
    parser = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0],
        epilog="examples:\n  benchmarks/scene_ablation.py --seeds own 1 2 3 --variants full no_diffuse\n"
               "  benchmarks/scene_ablation.py --scene skewed_walls --variants full no_clutter --poses truth-held\n"
               "  benchmarks/scene_ablation.py --seeds own 1 2 3 --variants full --sources 5   # what the RMS is made of",
        formatter_class=argparse.RawDescriptionHelpFormatter)
    office_surveys.add_arguments(parser, "/tmp/thrumapper_ablation")
    parser.add_argument("--variants", nargs="+", default=list(VARIANTS), choices=list(VARIANTS),
                        metavar="VARIANT", help="which variants (default all: " + ", ".join(VARIANTS) + ")")
    parser.add_argument("--poses", choices=list(POSES), default="odometry",
                        help="the fusion's poses: the survey's odometry (default, as thrumapper-map), the true "
                             "poses given as odometry (truth), or the true poses kept (truth-held: no pose "
                             "correction)")
    parser.add_argument("--jobs", type=int, default=2, help="surveys mapped at once (default 2)")
    parser.add_argument("--json", metavar="FILE", help="also write every survey's numbers to FILE")
    parser.add_argument("--sources", type=int, default=0, metavar="N",
                        help="after the table, each variant's N largest sources of detection error per class, "
                             "pooled over the seeds (default 0: none)")
    args = parser.parse_args(argv)
    if args.jobs < 1:
        parser.error("--jobs must be >= 1")
    if args.sources < 0:
        parser.error("--sources must be >= 0")
    scene_yaml = office_surveys.scene_path(parser, args)
    try:
        paths = {v: variant_scene(scene_yaml, v, args.out) for v in args.variants}
    except VariantError as err:
        parser.error(f"--variants: {err}")
    jobs = [(args.scene, v, seed, paths[v], args.out, args.poses) for v in args.variants for seed in args.seeds]

    def fmt(value, digits=3):
        return "   -  " if value is None else f"{value:6.{digits}f}"

    rows = []
    with Pool(args.jobs) as pool:
        for i, row in enumerate(pool.imap_unordered(score, jobs), 1):
            rows.append(row)
            print(f"[{i}/{len(jobs)}] {row['variant']} seed {row['seed']}: line of sight {fmt(row['los_m'])} m",
                  file=sys.stderr, flush=True)
    if args.json:
        with open(args.json, "w", encoding="utf-8") as handle:
            json.dump(rows, handle, indent=1)

    def percent(value):
        return "   - " if value is None else f"{100.0 * value:4.0f}%"

    print(f"{args.scene}, seeds {' '.join(args.seeds)}, poses: {args.poses}; medians over the seeds")
    print(f"{'variant':16s} {'LoS m':>6s} {'hidden':>6s} {'LoS cov':>7s} {'hid cov':>7s} {'traj m':>6s} {'|turn|':>6s} "
          f"{'|drift err|':>11s} {'LoS*':>6s} {'hid*':>6s}")
    for v in args.variants:
        mine = [r for r in rows if r["variant"] == v]
        print(f"{v:16s} {fmt(_median(mine, 'los_m'))} {fmt(_median(mine, 'hidden_m'))} "
              f"{percent(_median(mine, 'los_coverage')):>7s} {percent(_median(mine, 'hidden_coverage')):>7s} "
              f"{fmt(_median(mine, 'trajectory_m'))} {fmt(_median(mine, 'turn_deg', True), 2)}° "
              f"{fmt(_median(mine, 'drift_error_deg_per_m', True))}°/m "
              f"{fmt(_median(mine, 'los_same_class_m'))} {fmt(_median(mine, 'hidden_same_class_m'))}")
    print("LoS*, hid*: the RMS without the detections on a true wall of the other class (class flips)")
    for v in args.variants if args.sources else ():
        mine = [r for r in rows if r["variant"] == v]
        for cls in evaluation.CLASSES:
            print(f"\n{v}, {cls}: detections more than 0.3 m off, share of the squared error over the seeds")
            found = pooled_sources(mine, cls)[:args.sources]
            for share, why, wall, count in found:
                where = "on a true wall of the other class" if why == "other_class" else "near no true wall, nearest"
                print(f"  {100.0 * share:5.1f} %  {count:4d} detections {where}: {wall}")
            if not found:
                print("  none")
    return 0


if __name__ == "__main__":
    sys.exit(main())
