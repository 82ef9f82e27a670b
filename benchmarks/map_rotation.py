#!/usr/bin/python3
# SPDX-License-Identifier: GPL-3.0-or-later
"""How much of a map's error is the whole map turned about the survey's start.

A map is drawn in the frame of the survey's first pose, and its heading there is the
odometry's. If the pose adjustment leaves the headings a fraction of a degree off (the
odometry's drift estimated low, a run of biased fits near the start), the corridor walls and
the trajectory come out turned together, and the error grows along the track: 0.5 degrees is
0.17 m at 20 m. This finds, for each map, the rotation about the true first pose that best
fits the map's trajectory onto the truth's (least squares over the poses, which the two files
hold one for one), and scores the map with thrumapper-eval as it is and turned back by it.

What the second score shows is the map's shape without its orientation; the first is what
the issue's targets are measured on (docs/mapping.md, "The map turned as a whole").

Usage: benchmarks/map_rotation.py MAP.geojson TRUTH.geojson [MAP TRUTH ...]
       (PYTHONPATH=build/test_modules, or the module installed)
"""
import argparse
import json
import math
import os
import sys
import tempfile

import numpy as np

from gnuradio.thrumapper import evaluation


def best_rotation(ours, true, pivot):
    """The angle (rad) that turns the points `ours` (T, 2) about `pivot` closest to `true`
    (T, 2) in the least-squares sense."""
    a, b = ours - pivot, true - pivot
    return math.atan2(float(np.sum(a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0])),
                      float(np.sum(a[:, 0] * b[:, 0] + a[:, 1] * b[:, 1])))


def turned(geojson, angle, pivot):
    """A copy of a map's GeoJSON dict with every coordinate turned by `angle` about `pivot`
    (and the trajectory's headings with them)."""
    c, s = math.cos(angle), math.sin(angle)
    rot = np.array([[c, -s], [s, c]])

    def turn(coords):
        arr = np.asarray(coords, float)
        if arr.ndim == 1:
            return ((arr - pivot) @ rot.T + pivot).tolist()
        return [turn(x) for x in coords]

    out = json.loads(json.dumps(geojson))
    for feature in out["features"]:
        geometry = feature.get("geometry")
        if geometry and geometry.get("coordinates") is not None:
            geometry["coordinates"] = turn(geometry["coordinates"])
        props = feature.get("properties", {})
        if props.get("kind") == "trajectory" and props.get("headings_rad") is not None:
            props["headings_rad"] = [h + angle for h in props["headings_rad"]]
        if props.get("normal") is not None and len(props["normal"]) == 2:
            props["normal"] = (rot @ np.asarray(props["normal"], float)).tolist()
    return out


def trajectory_pairs(files, tool):
    """[(map path, truth path, map, truth)] (evaluation.load_map's) of the MAP TRUTH pairs in
    `files`, whose trajectories must hold one pose for one; None when a file does not load or
    the trajectories do not match, said on stderr prefixed by `tool`."""
    pairs = []
    for map_path, truth_path in zip(files[::2], files[1::2]):
        try:
            ours = evaluation.load_map(map_path, f"map {map_path}")
            truth = evaluation.load_map(truth_path, f"truth {truth_path}")
        except evaluation.MapFormatError as error:
            print(f"{tool}: {error}", file=sys.stderr)
            return None
        if ours.trajectory is None or truth.trajectory is None or len(ours.trajectory) != len(truth.trajectory):
            print(f"{tool}: {map_path}: the map and the truth need trajectories of the same length", file=sys.stderr)
            return None
        pairs.append((map_path, truth_path, ours, truth))
    return pairs


def scores(path, truth_path):
    s = evaluation.score_map(path, truth_path)
    cls = s["classes"]
    return (cls["line_of_sight"]["detections"]["rms_m"], cls["hidden"]["detections"]["rms_m"],
            (s.get("trajectory") or {}).get("rms_m"))


def pair_files(argv, doc, script):
    """The MAP TRUTH ... file names of a command line (argv; a script's docstring `doc` and
    name `script` for its --help), refused with a usage error unless they come in pairs."""
    parser = argparse.ArgumentParser(
        description=doc.split("\n\n")[0],
        epilog=f"Example, after ./scripts/demo.sh: benchmarks/{script} out/map.geojson "
               "out/paper_4_4_corridor_corner.truth.geojson")
    parser.add_argument("files", nargs="+", metavar="MAP TRUTH", help="pairs of a map and its truth (GeoJSON)")
    args = parser.parse_args(argv)
    if len(args.files) % 2:
        parser.error("expected pairs MAP TRUTH: got an odd number of files")
    return args.files


def main(argv=None):
    pairs = trajectory_pairs(pair_files(argv, __doc__, "map_rotation.py"), "map_rotation.py")
    if pairs is None:
        return 2
    fmt = lambda v: "  –  " if v is None else f"{v:.3f}"  # noqa: E731
    print(f"{'map':40s} {'turn':>7s}  {'LoS':>13s}  {'hidden':>13s}  {'trajectory':>13s}")
    print(f"{'':40s} {'deg':>7s}  {'as is  turned':>13s}  {'as is  turned':>13s}  {'as is  turned':>13s}")
    rows = []
    for map_path, truth_path, ours, truth in pairs:
        pivot = truth.trajectory[0]
        angle = best_rotation(ours.trajectory, truth.trajectory, pivot)
        with open(map_path) as f:
            data = json.load(f)
        with tempfile.TemporaryDirectory() as tmp:
            back = os.path.join(tmp, "turned.geojson")
            with open(back, "w") as f:
                json.dump(turned(data, angle, pivot), f)
            before, after = scores(map_path, truth_path), scores(back, truth_path)
        rows.append((math.degrees(angle), before, after))
        print(f"{os.path.basename(map_path)[:40]:40s} {math.degrees(angle):+7.2f}  "
              + "  ".join(f"{fmt(b)} {fmt(a)}" for b, a in zip(before, after)))
    if len(rows) > 1:
        turns = np.array([r[0] for r in rows])
        print(f"turn: mean {np.mean(turns):+.2f} deg, mean magnitude {np.mean(np.abs(turns)):.2f} deg")
        for n, name in enumerate(("LoS", "hidden", "trajectory")):
            b = [r[1][n] for r in rows if r[1][n] is not None]
            a = [r[2][n] for r in rows if r[2][n] is not None]
            if b:
                print(f"{name} median: {np.median(b):.3f} m as is, {np.median(a):.3f} m turned back")
    return 0


if __name__ == "__main__":
    sys.exit(main())
