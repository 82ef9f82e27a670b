#!/usr/bin/python3
# SPDX-License-Identifier: GPL-3.0-or-later
"""The mapping accuracy table of docs/mapping.md: every example scene simulated
(thrumapper-sim), mapped (thrumapper-map) and scored against its truth (thrumapper-eval).

For each scene it runs, in this process, exactly what these commands do:

    thrumapper-sim examples/scenes/SCENE.yaml --out OUT --quiet
    thrumapper-map OUT/SCENE.sigmf-meta --geojson OUT/SCENE.map.geojson --png OUT/SCENE.map.png \\
        --truth OUT/SCENE.truth.geojson --stats OUT/SCENE.stats.json --quiet [EXTRA]
    thrumapper-eval OUT/SCENE.map.geojson OUT/SCENE.truth.geojson --json

The column "LoS RMS aligned" scores the map moved onto the true trajectory first
(thrumapper-eval --align): its shape, without its frame's turn about the first pose.

EXTRA is --system-delay-s for the office scenes, whose survey does not state the delay and
whose TX null hides the direct path it would be measured on (docs/mapping.md). Surveys
already in OUT are reused (delete OUT to simulate again). Prints a Markdown table.

With --seeds, each scene is simulated again with each of these seeds (thrumapper-sim --seed:
other noise, impairments, odometry errors and scatterers, the same building) into OUT/seed-N/,
and after its rows a row of the medians and one of the ranges: the office maps move by
several centimetres between runs that differ in nothing that matters (docs/mapping.md), so
one survey is one draw, and a change is worth keeping when it moves the medians.

With --set NAME=VALUE (repeatable) a WallFusion class constant is set for the run (VALUE
read as JSON: true, 15.0, "text"), to measure the maps with one of the fusion's choices
changed, as docs/mapping.md does, e.g.

    benchmarks/map_accuracy.py --scenes office_floor office_floor_drift --seeds 1 2 3 \
        --set END_WALL_ON_MAPPED=false --out out/map_accuracy_off

Usage: benchmarks/map_accuracy.py [--out DIR] [--scenes NAME ...] [--seeds N ...] [--set NAME=VALUE ...]
           [-- EXTRA thrumapper-map ARGS]
"""
import argparse
import contextlib
import io
import json
import math
import os
import sys
import time

from gnuradio.thrumapper import cli_map, cli_sim, evaluation
from gnuradio.thrumapper.wall_fusion import WallFusion

HERE = os.path.dirname(os.path.abspath(__file__))
SCENES_DIR = os.path.join(HERE, "..", "examples", "scenes")

# scene -> extra thrumapper-map arguments
SCENES = {
    "paper_4_2_wall_0p7m": [],
    "paper_4_2_wall_2p2m": [],
    "paper_4_3_hidden_1p5m": [],
    "paper_4_3_hidden_2p2m": [],
    "paper_4_4_corridor_corner": [],
    "skewed_walls": [],
    "office_floor": ["--system-delay-s", "31e-9"],
    "office_floor_drift": ["--system-delay-s", "31e-9"],
}
PAPER_CORNER = (6.525, -0.7)  # §4.4–4.5: where the line-of-sight wall meets the end wall


def quiet(function, argv):
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = function(argv)
    if code != 0:
        raise RuntimeError(f"{function.__module__} {' '.join(argv)} failed:\n{err.getvalue()}")
    return out.getvalue()


def measured_as_detections(map_path):
    """The map with its measured echoes scored as the detections (before fusion)."""
    with open(map_path, encoding="utf-8") as handle:
        data = json.load(handle)
    features = []
    for f in data["features"]:
        kind = f["properties"].get("kind")
        if kind == "detections":
            continue
        if kind == "echoes":
            f = dict(f, properties=dict(f["properties"], kind="detections"))
        features.append(f)
    return dict(data, features=features)


def fmt(value, scale=1.0, digits=3, unit=""):
    return "–" if value is None else f"{value * scale:.{digits}f}{unit}"


def corner_check(map_path, truth_path):
    """Distance from the §4.4 corner to the nearest map corner, and the RMS of the fused
    line-of-sight detections within 1.5 m of it (are the walls near it pulled off?)."""
    m = evaluation.load_map(map_path)
    t = evaluation.load_map(truth_path)
    corner = None
    if m.corners:
        corner = min(math.hypot(c["position"][0] - PAPER_CORNER[0], c["position"][1] - PAPER_CORNER[1]) for c in m.corners)
    import numpy as np
    near = [d["points"] for d in m.detections if d["class"] == "line_of_sight"]
    points = np.vstack(near) if near else np.zeros((0, 2))
    points = points[np.hypot(points[:, 0] - PAPER_CORNER[0], points[:, 1] - PAPER_CORNER[1]) < 1.5]
    starts, ends = evaluation._segments([w["coordinates"] for w in t.walls if w["class"] == "line_of_sight"])
    rms = None
    if len(points):
        rms = float(np.sqrt(np.mean(evaluation.distance_to_segments(points, starts, ends) ** 2)))
    return corner, rms


def csi_walls_check(map_path, truth_path):
    """The walls found on the CSI alone (end and side walls, no echo of their own, so not in
    the detection RMS): their RMS distance to the nearest true wall face, sampled every 1 cm
    along them, and their length. (None, 0.0) when the map has none."""
    import numpy as np

    with open(map_path, encoding="utf-8") as handle:
        features = json.load(handle)["features"]
    lines = [np.asarray(f["geometry"]["coordinates"], float) for f in features
             if f["properties"].get("kind") == "wall" and f["properties"].get("source") in ("end_wall", "side_wall")]
    if not lines:
        return None, 0.0
    t = evaluation.load_map(truth_path)
    points, weights = evaluation._sample(lines, 0.01)
    starts, ends = evaluation._segments([w["coordinates"] for w in t.walls])
    distances = evaluation.distance_to_segments(points, starts, ends)
    return float(np.sqrt(np.sum(weights * distances ** 2) / np.sum(weights))), float(np.sum(weights))


def main(argv=None):
    argv = list(sys.argv[1:] if argv is None else argv)
    extra = []
    if "--" in argv:
        extra = argv[argv.index("--") + 1:]
        argv = argv[:argv.index("--")]
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default="out/map_accuracy", help="directory for surveys and maps")
    parser.add_argument("--scenes", nargs="*", default=list(SCENES), help="scenes to run")
    parser.add_argument("--seeds", nargs="*", type=int, default=None,
                        help="simulate each scene with each of these seeds instead of its own (median and range rows)")
    parser.add_argument("--set", action="append", default=[], metavar="NAME=VALUE",
                        help="set a WallFusion class constant for this run (VALUE as JSON: true, 15.0, \"text\")")
    args = parser.parse_args(argv)
    for name, value in fusion_constants(parser, args.set).items():
        setattr(WallFusion, name, value)
        print(f"WallFusion.{name} = {value!r}")
    unknown = [n for n in args.scenes if n not in SCENES]
    if unknown:
        parser.error(f"unknown scenes {unknown}; known: {', '.join(SCENES)}")
    rows = []
    for name in args.scenes:
        if args.seeds is None:
            rows.append(run_scene(name, args.out, extra))
            continue
        runs = [run_scene(name, os.path.join(args.out, f"seed-{seed}"), extra, seed) for seed in args.seeds]
        rows += runs + summary_rows(name, runs)
    print_table(rows)
    return 0


def fusion_constants(parser, settings):
    """{name: value} of the --set NAME=VALUE options (parser.error on a malformed one or a
    name that is not an upper-case WallFusion constant)."""
    out = {}
    for setting in settings:
        name, sep, text = setting.partition("=")
        if not sep or not name.isupper() or not hasattr(WallFusion, name):
            parser.error(f"--set {setting}: expected NAME=VALUE with NAME a WallFusion constant (e.g. END_WALL_ON_MAPPED=false)")
        try:
            out[name] = json.loads(text)
        except json.JSONDecodeError:
            parser.error(f"--set {setting}: VALUE is not JSON (true, false, 15.0, \"text\")")
    return out


SUMMARISED = ("los_rms", "los_raw_rms", "los_aligned_rms", "hidden_rms", "hidden_raw_rms", "los_cov", "hidden_cov", "false_frac",
              "corner_m", "near_corner_rms", "traj_rms", "csi_rms", "csi_length", "s_per_pose")


def summary_rows(name, runs):
    """A row of the medians over the runs, and one of their ranges (max - min)."""
    import numpy as np

    med = {"scene": f"{name}, median", "corners": "–", "doors": "–"}
    spread = {"scene": f"{name}, range", "corners": "–", "doors": "–"}
    for key in SUMMARISED:
        values = [r[key] for r in runs if r[key] is not None]
        med[key] = float(np.median(values)) if values else None
        spread[key] = float(max(values) - min(values)) if values else None
    return [med, spread]


def doorways(openings):
    """The open doorways column: found / true, the jambs' RMS error, and the map's
    openings near no true one; "–" where neither map has any."""
    if not openings or not (openings["truth"] or openings["map"]):
        return "–"
    jambs = "" if openings["jamb_error_rms_m"] is None else f" ({openings['jamb_error_rms_m']:.2f})"
    false = f", {openings['unmatched_map']} false" if openings["unmatched_map"] else ""
    return f"{openings['found']}/{openings['truth']}{jambs}{false}"


def run_scene(name, out, extra, seed=None):
    """Simulate (unless OUT has the survey), map and score one scene: a row of the table."""
    os.makedirs(out, exist_ok=True)
    meta = os.path.join(out, name + ".sigmf-meta")
    truth = os.path.join(out, name + ".truth.geojson")
    if not (os.path.exists(meta) and os.path.exists(truth)):
        quiet(cli_sim.main, [os.path.join(SCENES_DIR, name + ".yaml"), "--out", out, "--quiet"] +
              ([] if seed is None else ["--seed", str(seed)]))
    map_path = os.path.join(out, name + ".map.geojson")
    stats_path = os.path.join(out, name + ".stats.json")
    started = time.perf_counter()
    quiet(cli_map.main, [meta, "--geojson", map_path, "--png", os.path.join(out, name + ".map.png"),
                         "--truth", truth, "--stats", stats_path, "--quiet"] + SCENES[name] + extra)
    elapsed = time.perf_counter() - started
    scores = json.loads(quiet(evaluation_cli, [map_path, truth, "--json"]))
    raw = evaluation.score_map(measured_as_detections(map_path), truth)
    # the map's shape: its frame's turn about the first pose taken out (thrumapper-eval --align)
    try:
        aligned = evaluation.score_map(evaluation.align_to_truth(map_path, truth)[0], truth)
        aligned_rms = aligned["classes"]["line_of_sight"]["detections"]["rms_m"]
    except evaluation.MapFormatError:  # a single pose: no trajectory to align by
        aligned_rms = None
    with open(stats_path, encoding="utf-8") as handle:
        stats = json.load(handle)
    c = scores["classes"]
    total_true = c["line_of_sight"]["truth_wall_length_m"] + c["hidden"]["truth_wall_length_m"]
    corner, near_rms = corner_check(map_path, truth) if name == "paper_4_4_corridor_corner" else (None, None)
    csi_rms, csi_length = csi_walls_check(map_path, truth)
    return {
        "scene": name if seed is None else f"{name} (seed {seed})",
        "los_rms": c["line_of_sight"]["detections"]["rms_m"],
        "los_raw_rms": raw["classes"]["line_of_sight"]["detections"]["rms_m"],
        "los_aligned_rms": aligned_rms,
        "hidden_rms": c["hidden"]["detections"]["rms_m"],
        "hidden_raw_rms": raw["classes"]["hidden"]["detections"]["rms_m"],
        "los_cov": c["line_of_sight"]["coverage"],
        "hidden_cov": c["hidden"]["coverage"],
        "false_frac": scores["false_wall_length_m"] / total_true if total_true else None,
        "corners": f"{scores['corners']['found']}/{scores['corners']['truth']}",
        "doors": doorways(scores.get("openings")),
        "corner_m": corner, "near_corner_rms": near_rms,
        "traj_rms": (scores["trajectory"] or {}).get("rms_m"),
        "csi_rms": csi_rms, "csi_length": csi_length,
        "s_per_pose": elapsed / max(stats["poses"], 1),
    }


def print_table(rows):
    header = ("| scene | LoS RMS fused (raw) m | LoS RMS aligned m | hidden RMS fused (raw) m | LoS coverage | hidden coverage | "
              "false wall / true length | corners found | §4.4 corner m (LoS RMS near it) | "
              "open doorways found (jambs RMS m) | trajectory RMS m | walls found on the CSI: RMS m (length m) | "
              "s/pose |")
    print(header)
    print("|---" * (header.count("|") - 1) + "|")
    for r in rows:
        print(f"| {r['scene']} | {fmt(r['los_rms'])} ({fmt(r['los_raw_rms'])}) | {fmt(r['los_aligned_rms'])} | "
              f"{fmt(r['hidden_rms'])} "
              f"({fmt(r['hidden_raw_rms'])}) | {fmt(r['los_cov'], 100, 1, ' %')} | {fmt(r['hidden_cov'], 100, 1, ' %')} | "
              f"{fmt(r['false_frac'], 100, 1, ' %')} | {r['corners']} | "
              f"{fmt(r['corner_m'], digits=2)} ({fmt(r['near_corner_rms'])}) | {r['doors']} | {fmt(r['traj_rms'])} | "
              f"{fmt(r['csi_rms'])} ({fmt(r['csi_length'], digits=1)}) | {fmt(r['s_per_pose'])} |")


def evaluation_cli(argv):
    from gnuradio.thrumapper import cli_eval
    return cli_eval.main(argv)


if __name__ == "__main__":
    sys.exit(main())
