#!/usr/bin/python3
# SPDX-License-Identifier: GPL-3.0-or-later
"""Rules for drawing the rooms' partitions, scored on the dips of the back walls' echo.

A partition between two rooms behind a corridor wall gives the track no echo of its own, but
the echo of the rooms' back wall all but vanishes where one of its legs runs along it
(docs/mapping.md, "Partitions"). Interference between two echoes makes dips too. For each
scene and seed (simulated once, thrumapper-sim --seed, kept under --out) this maps the survey
as thrumapper-map does, keeps every pose of the last mapping pass whose back-wall gain falls
under --limit of the line's median nearby (its ratio, whether it is deep, whether a room's
corner answers at it on the CSI), and scores each rule below on them: the dips under the
rule's ratio, grouped within WallFusion.PARTITION_MERGE_M along their line, each group
that the rule takes a partition at its dips' depth-weighted mean. A true partition (a truth
wall named partition_*) is hit when a partition lies within --tolerance of it; a partition
with none that near is false. The reach to the corridor wall that the fusion also asks is
not checked, so the counts may differ by one or two from the partitions the maps draw.

Rules (docs/mapping.md, "A partition's shadow over its neighbouring poses"):
  main       dips under 0.3; two poses, or one deep, or a corner at it
  all-0.35, all-0.4, all-0.45
             dips under that ratio, as main
  core-0.3   dips under 0.4 with one pose under 0.3 in each group (the fusion's default)
  core-0.25  the same, the core under 0.25
  no-corner  core-0.3 without the corners' confirmation of a lone shallow dip

Usage: benchmarks/partition_rules.py [--out DIR] [--scenes office_floor office_floor_drift]
           [--seeds own 1 2 ...] [--jobs 2]
       (PYTHONPATH=build/test_modules, or the module installed; about 40 s a survey on one core)
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
from gnuradio.thrumapper.wall_fusion import WallFusion  # noqa: E402

import office_surveys  # noqa: E402


def _main_rule(ratio, deep, corner):
    return len(ratio) >= 2 or bool(deep.all()) or bool(corner.any())


def _core_rule(core, corners=True):
    def rule(ratio, deep, corner):
        if not np.any(ratio < core):
            return False
        return len(ratio) >= 2 or bool(deep.all()) or (corners and bool(corner.any()))
    return rule


# name: (ratio the dips are taken under, the rule a group of them must meet)
RULES = {
    "main": (0.3, _main_rule),
    "all-0.35": (0.35, _main_rule),
    "all-0.4": (0.4, _main_rule),
    "all-0.45": (0.45, _main_rule),
    "core-0.3": (0.4, _core_rule(0.3)),
    "core-0.25": (0.4, _core_rule(0.25)),
    "no-corner": (0.4, _core_rule(0.3, corners=False)),
}


def dips_of(fusion, limit):
    """Wraps fusion._partition_dips so that it also keeps, from its last call, every dip under
    `limit` as [{"points", "ratio", "deep", "corner", "centre", "direction"}] (one per
    line), while handing the fusion the dips it asked for."""
    kept = []

    def wrapped(state, poses, wall_cls, ratio_limit=None, continued_spans=None):
        out = WallFusion._partition_dips(fusion, state, poses, wall_cls, limit, continued_spans)
        asked = fusion.PARTITION_GAIN_RATIO if ratio_limit is None else ratio_limit
        kept.clear()
        for line, points, deep, ratio in out:
            t = (points - line["centre"]) @ line["direction"]
            kept.append({"points": points.tolist(), "ratio": ratio.tolist(), "deep": deep.tolist(),
                         "corner": [bool(fusion._corner_at(line, float(tq), poses)) for tq in t],
                         "centre": line["centre"].tolist(), "direction": line["direction"].tolist()})
        return WallFusion._dips_under(out, asked)

    fusion._partition_dips = wrapped
    return kept


def drawn(lines, ratio_limit, rule, merge_m):
    """World points of the partitions `rule` takes from the dumped dips of `lines`."""
    out = []
    for line in lines:
        points, ratio = np.array(line["points"], float).reshape(-1, 2), np.array(line["ratio"], float)
        deep, corner = np.array(line["deep"], bool), np.array(line["corner"], bool)
        under = ratio < ratio_limit
        points, ratio, deep, corner = points[under], ratio[under], deep[under], corner[under]
        if not len(points):
            continue
        t = (points - np.array(line["centre"])) @ np.array(line["direction"])
        for members in WallFusion.dip_groups(t, merge_m):
            if rule(ratio[members], deep[members], corner[members]):
                out.append(WallFusion.dip_place(points[members], ratio[members], ratio_limit))
    return out


def truth_partitions_of(truth_path):
    """{name: [(start, end) of each face]} of the truth walls named partition_*: the truth
    draws a partition's two faces, one name for both."""
    with open(truth_path) as f:
        features = json.load(f)["features"]
    out = {}
    for feature in features:
        props = feature.get("properties", {})
        name = props.get("name") or ""
        if props.get("kind") == "wall" and name.startswith("partition"):
            coords = np.array(feature["geometry"]["coordinates"], float)
            out.setdefault(name, []).append((coords[0], coords[-1]))
    return out


def survey(job):
    scene, seed, out, limit, tolerance_m = job
    path = os.path.join(office_surveys.SCENES_DIR, scene + ".yaml")
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        _, info, truth_path = office_surveys.mapped(path, scene, seed, out, build=False)
        fusion = office_surveys.refilled(info)
        lines = dips_of(fusion, limit)
        fusion.build_map()
    faces = truth_partitions_of(truth_path)
    out = {}
    for name, (ratio_limit, rule) in RULES.items():
        hit, false = set(), 0
        for point in drawn(lines, ratio_limit, rule, fusion.PARTITION_MERGE_M):
            near = {wall for wall, pair in faces.items() for a, b in pair
                    if float(evaluation.distance_to_segments(point[None, :], a[None, :], b[None, :])[0])
                    <= tolerance_m}
            hit |= near
            false += not near
        out[name] = (len(hit), false)
    return {"scene": scene, "seed": seed, "partitions": len(faces), "rules": out}


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter,
                                     epilog="\n\n".join(__doc__.split("\n\n")[1:]))
    parser.add_argument("--out", default="/tmp/thrumapper-partition-rules",
                        help="where the simulated surveys are kept (reused when there)")
    parser.add_argument("--scenes", nargs="+", default=["office_floor", "office_floor_drift"],
                        help="example scene names (examples/scenes/NAME.yaml)")
    parser.add_argument("--seeds", nargs="+", default=["own"] + [str(n) for n in range(1, 12)],
                        help="seeds to simulate each scene with ('own': the scene's)")
    parser.add_argument("--limit", type=float, default=0.5,
                        help="keep the dips under this ratio of the line's median (default 0.5)")
    parser.add_argument("--tolerance-m", type=float, default=0.3,
                        help="a partition within this of a true one hits it (default 0.3 m, "
                             "thrumapper-eval's coverage tolerance)")
    parser.add_argument("--jobs", type=int, default=2, help="surveys mapped at once (default 2)")
    args = parser.parse_args(argv)
    for scene in args.scenes:
        if not os.path.exists(os.path.join(office_surveys.SCENES_DIR, scene + ".yaml")):
            parser.error(f"--scenes: no scene {scene} in {office_surveys.SCENES_DIR}")
    if any(seed != "own" and not seed.isdigit() for seed in args.seeds):
        parser.error(f"--seeds: expected 'own' or whole numbers, got {' '.join(args.seeds)}")
    if not 0.0 < args.limit <= 1.0:
        parser.error(f"--limit: expected a ratio in (0, 1], got {args.limit}")
    if max(limit for limit, _ in RULES.values()) > args.limit:
        parser.error(f"--limit: the rules take dips up to {max(limit for limit, _ in RULES.values())}")
    jobs = [(scene, seed, args.out, args.limit, args.tolerance_m) for scene in args.scenes for seed in args.seeds]
    totals = {name: [0, 0] for name in RULES}
    true_total = 0
    with Pool(max(1, args.jobs)) as pool:
        for n, row in enumerate(pool.imap_unordered(survey, jobs), 1):
            true_total += row["partitions"]
            for name, (hit, false) in row["rules"].items():
                totals[name][0] += hit
                totals[name][1] += false
            print(f"[{n}/{len(jobs)}] {row['scene']} seed {row['seed']}: " +
                  ", ".join(f"{name} {hit}/{false}" for name, (hit, false) in row["rules"].items()),
                  file=sys.stderr, flush=True)
    print(f"{len(jobs)} surveys, {true_total} true partitions (hit / false, within {args.tolerance_m} m)")
    print(f"{'rule':<12} {'hit':>5} {'false':>6}")
    for name, (hit, false) in totals.items():
        print(f"{name:<12} {hit:>5} {false:>6}")


if __name__ == "__main__":
    main()
