#!/usr/bin/python3
# SPDX-License-Identifier: GPL-3.0-or-later
"""The main job, part two: a floor plan from a corridor scan (the paper's §4.4–4.5).

Simulates the trolley moving 5.6 m along a corridor past a room (20 cm steps, 4 frames a
pose), maps it with thrumapper-map (calibration, JADE with successive cancellation, wall
fusion, pose correction) and scores the map against the scene's truth with thrumapper-eval.
Everything it runs is what a user runs by hand:

    thrumapper-sim examples/scenes/paper_4_4_corridor_corner.yaml --out out
    thrumapper-map out/paper_4_4_corridor_corner.sigmf-meta --geojson out/map.geojson --png out/map.png
    thrumapper-eval out/map.geojson out/paper_4_4_corridor_corner.truth.geojson
"""
import argparse
import os
import subprocess
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
SCENE = os.path.join(HERE, "scenes", "paper_4_4_corridor_corner.yaml")


def run(cmd):
    print("$ " + " ".join(cmd), flush=True)
    subprocess.run(cmd, check=True)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", default="out", help="output folder (default ./out)")
    ap.add_argument("--scene", default=SCENE, help="scene file (default: the §4.4 corridor scan)")
    args = ap.parse_args()
    os.makedirs(args.out, exist_ok=True)
    name = os.path.splitext(os.path.basename(args.scene))[0]
    meta = os.path.join(args.out, name + ".sigmf-meta")
    geojson = os.path.join(args.out, "map.geojson")
    png = os.path.join(args.out, "map.png")
    run(["thrumapper-sim", args.scene, "--out", args.out, "--quiet"])
    run(["thrumapper-map", meta, "--geojson", geojson, "--png", png, "--quiet"])
    run(["thrumapper-eval", geojson, os.path.join(args.out, name + ".truth.geojson")])
    print(f"\nwrote {geojson} and {png}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
