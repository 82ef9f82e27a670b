#!/usr/bin/python3
# SPDX-License-Identifier: GPL-3.0-or-later
"""The main job, for now: JADE finds a corridor wall and the wall hidden behind it.

Simulates the paper's §4.3 geometry (the trolley 0.6 m from a 15 cm plasterboard corridor
wall, a second wall 1.5 m behind it) with thrumapper-sim, runs thrumapper-jade on the survey,
prints each path found next to the geometric truth, and writes the angle x delay surface with
the truth marked. Everything it runs is what a user runs by hand:

    thrumapper-sim examples/scenes/paper_4_3_hidden_1p5m.yaml --out out
    thrumapper-jade out/paper_4_3_hidden_1p5m.sigmf-meta --paths 6 --png out/surface.png
"""
import argparse
import json
import math
import os
import subprocess
import sys

import numpy as np

from gnuradio.thrumapper import building_sim, jade_pipeline, scene, survey

HERE = os.path.dirname(os.path.abspath(__file__))
SCENE = os.path.join(HERE, "scenes", "paper_4_3_hidden_1p5m.yaml")


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", default="out", help="output folder (default ./out)")
    ap.add_argument("--scene", default=SCENE, help="scene file (default: the §4.3 1.5 m scene)")
    args = ap.parse_args()
    os.makedirs(args.out, exist_ok=True)
    name = os.path.splitext(os.path.basename(args.scene))[0]

    print(f"$ thrumapper-sim {args.scene} --out {args.out} --quiet")
    subprocess.run(["thrumapper-sim", args.scene, "--out", args.out, "--quiet"], check=True)
    meta = os.path.join(args.out, name + ".sigmf-meta")
    png = os.path.join(args.out, "surface.png")
    print(f"$ thrumapper-jade {meta} --paths 6 --png {png}")
    run = subprocess.run(["thrumapper-jade", meta, "--paths", "6", "--png", png, "--quiet"],
                         check=True, capture_output=True, text=True)
    groups = [json.loads(line) for line in run.stdout.splitlines() if line.strip()]

    sc = scene.load_scene(args.scene)
    sv = survey.read_survey(meta)
    pose_true = sc.poses[0]
    truth = [t for t in building_sim.path_truth(sc, pose_true)
             if t["kind"] in ("direct", "wall", "wall_through")]

    print(f"\n{len(groups)} pose group(s); the first, frames {groups[0]['frames']}:")
    print(f"{'found: angle':>14} {'delay':>9} {'power':>9}   {'nearest truth':<14} {'angle':>8} {'delay':>9}  {'error':>16}")
    for p in groups[0]["paths"]:
        def distance(t):
            da = (p["aoa_deg"] - t["aoa_deg"] + 180) % 360 - 180
            return (da / 5.0) ** 2 + ((p["delay_s"] - t["delay_s"]) / 1e-9) ** 2
        t = min(truth, key=distance)
        da = (p["aoa_deg"] - t["aoa_deg"] + 180) % 360 - 180
        dd = (p["delay_s"] - t["delay_s"]) * 1e9
        close = distance(t) < 4
        found = f"{p['aoa_deg']:13.2f}° {p['delay_s']*1e9:7.3f}ns {p['power']:9.2e}   "
        if close:
            print(found + f"{t['kind']:<14} {t['aoa_deg']:7.2f}° {t['delay_s']*1e9:7.3f}ns  "
                  f"{da:+6.2f}° {dd:+6.3f}ns")
        else:
            print(found + "(no wall: residue of the near-field direct path, or clutter)")
    print("\ngeometric truth (FORMATS.md delays, TX centre to RX centre):")
    for t in truth:
        print(f"  {t['kind']:<13} angle {t['aoa_deg']:7.2f}°  delay {t['delay_s']*1e9:7.3f} ns  "
              f"path {t['length_m']:.3f} m  power {t['amplitude']**2:.2e}")

    # the surface once more, with the truth marked
    result = next(jade_pipeline.run_survey(sv, jade_pipeline.JadeSettings(max_paths=6)))
    jade_pipeline.plot_surface(result, png, truth=truth,
                               title="§4.3: corridor wall and the wall 1.5 m behind it (○ geometry, + JADE)")
    print(f"\nwrote {png}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
