#!/usr/bin/python3
# SPDX-License-Identifier: GPL-3.0-or-later
"""What moving the finished map onto the carrier phase's poses does to the maps.

The fusion's mapping rounds alternate the map and a pose adjustment on the walls' per-pose
fits; those fits carry runs of bias that the adjustment takes for a heading drift, and the map
turns with the track (docs/mapping.md, "The map turned as a whole"). With
WallFusion.PHASE_POSES_FOR_GEOMETRY (on by default) the finished map, its decisions kept, is
moved onto the poses of one more adjustment that also uses each line-of-sight wall's path
change from pose to pose on the carrier's phase ("The map moved onto the carrier phase's
poses").

For each scene and seed (simulated once, thrumapper-sim --seed, kept under --out) this runs
JADE once and maps the survey twice from its results, without the move and with it, scores
both with thrumapper-eval against the truth and prints one row per survey and the medians:
line-of-sight and hidden detection RMS, coverage, false wall share, trajectory RMS.

Usage: benchmarks/phase_poses.py [--out DIR] [--scenes office_floor office_floor_drift]
           [--seeds own 1 2 ...] [--jobs 2]
       (PYTHONPATH=build/test_modules, or the module installed; about 80 s a survey on one core)
"""
import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse  # noqa: E402
import contextlib  # noqa: E402
import io  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402
from multiprocessing import Pool  # noqa: E402

import numpy as np  # noqa: E402

from gnuradio.thrumapper import evaluation  # noqa: E402

import office_surveys  # noqa: E402

MODES = (("rounds", False), ("moved", True))


def scored(fused, truth):
    """thrumapper-eval's figures of a FusedMap against the truth (evaluation.MapData)."""
    score = evaluation.score_map(fused.to_geojson(), truth)
    los, hidden = score["classes"]["line_of_sight"], score["classes"]["hidden"]
    true_m = los["truth_wall_length_m"] + hidden["truth_wall_length_m"]
    return {"los_m": los["detections"]["rms_m"], "hidden_m": hidden["detections"]["rms_m"],
            "los_coverage": los["coverage"], "hidden_coverage": hidden["coverage"],
            "false_share": (los["false_wall_length_m"] + hidden["false_wall_length_m"]) / true_m,
            "trajectory_m": (score["trajectory"] or {}).get("rms_m")}


def survey(job):
    scene, seed, out = job
    path = os.path.join(office_surveys.SCENES_DIR, scene + ".yaml")
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        _, info, truth_path = office_surveys.mapped(path, scene, seed, out, build=False)
        truth = evaluation.load_map(truth_path, "truth")
        row = {"scene": scene, "seed": seed}
        for name, on in MODES:
            fused = office_surveys.remapped(info, PHASE_POSES_FOR_GEOMETRY=on)
            row[name] = scored(fused, truth)
            if on:
                row["phase_drift_deg_per_m"] = fused.stats.get("phase_poses_drift_deg_per_m")
                row["rounds_drift_deg_per_m"] = fused.stats.get("odometry_drift_deg_per_m")
    return row


def text(value, digits=3):
    return "-" if value is None else f"{value:.{digits}f}"


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter,
                                     epilog="\n\n".join(__doc__.split("\n\n")[1:]))
    parser.add_argument("--out", default="/tmp/thrumapper_phase_poses", help="where the simulated surveys are kept")
    parser.add_argument("--scenes", nargs="+", default=["office_floor", "office_floor_drift"],
                        help="example scene names (examples/scenes/NAME.yaml)")
    parser.add_argument("--seeds", nargs="+", default=["own", "1", "2", "3"],
                        help="seeds to simulate each scene with ('own': the scene's)")
    parser.add_argument("--jobs", type=int, default=2, help="surveys mapped at once (default 2)")
    parser.add_argument("--json", help="write the rows to this file too")
    args = parser.parse_args(argv)
    if args.jobs < 1:
        parser.error("--jobs must be >= 1")
    for scene in args.scenes:
        if not os.path.exists(os.path.join(office_surveys.SCENES_DIR, scene + ".yaml")):
            parser.error(f"--scenes: no scene {scene}")
    if any(seed != "own" and not seed.isdigit() for seed in args.seeds):
        parser.error(f"--seeds: expected 'own' or whole numbers, got {' '.join(args.seeds)}")
    jobs = [(scene, seed, args.out) for scene in args.scenes for seed in args.seeds]
    keys = ("los_m", "hidden_m", "los_coverage", "hidden_coverage", "false_share", "trajectory_m")
    print("survey                      mode    LoS m  hidden m  LoS cov  hid cov  false  trajectory m")
    rows = []
    with Pool(args.jobs) as pool:
        for row in pool.imap(survey, jobs):
            rows.append(row)
            for name, _ in MODES:
                r = row[name]
                print(f"{row['scene'] + ' ' + row['seed']:27s} {name:7s} {text(r['los_m']):>6s} {text(r['hidden_m']):>9s}"
                      f" {text(r['los_coverage'], 2):>8s} {text(r['hidden_coverage'], 2):>8s} {text(r['false_share']):>6s}"
                      f" {text(r['trajectory_m']):>12s}", flush=True)
    print(f"\nmedians over {len(rows)} surveys (trajectory: surveys within 0.10 m)")
    for name, _ in MODES:
        med = {k: np.median([r[name][k] for r in rows if r[name][k] is not None]) for k in keys}
        within = sum(1 for r in rows if r[name]["trajectory_m"] is not None and r[name]["trajectory_m"] <= 0.10)
        mean_los = np.mean([r[name]["los_m"] for r in rows if r[name]["los_m"] is not None])
        print(f"{name:7s} LoS {med['los_m']:.3f} m (mean {mean_los:.3f}), hidden {med['hidden_m']:.3f} m, coverage "
              f"{100 * med['los_coverage']:.1f} / {100 * med['hidden_coverage']:.1f} %, false {100 * med['false_share']:.1f} %,"
              f" trajectory {med['trajectory_m']:.3f} m ({within} within 0.10 m)")
    better = {k: sum(1 for r in rows if None not in (r["moved"][k], r["rounds"][k]) and r["moved"][k] < r["rounds"][k] - 0.005)
              for k in ("los_m", "hidden_m", "trajectory_m")}
    worse = {k: sum(1 for r in rows if None not in (r["moved"][k], r["rounds"][k]) and r["moved"][k] > r["rounds"][k] + 0.005)
             for k in ("los_m", "hidden_m", "trajectory_m")}
    print("moved better / worse by more than 5 mm: " + ", ".join(f"{k} {better[k]} / {worse[k]}" for k in better))
    if args.json:
        with open(args.json, "w", encoding="utf-8") as handle:
            json.dump(rows, handle, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
