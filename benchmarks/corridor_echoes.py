#!/usr/bin/python3
# SPDX-License-Identifier: GPL-3.0-or-later
"""What JADE finds of the two corridor walls, pose by pose, against their geometry.

A corridor driven down its middle puts both corridor walls at one delay: their echoes reach
the receiver at the same time from two sides, and in the frequency domain they are the same
signal (coherent), which smoothing over subcarriers cannot separate. The office scenes' TX
beam faces south, so the north wall's echo is about 6 dB weaker than the south wall's. And
what the TX chains' errors leave of the direct path (benchmarks/direct_leak.py) arrives
4.7 ns before the walls' echoes, inside one delay cell of them (1/120 MHz = 8.3 ns), and takes
some of JADE's paths as a spray of weak far-field paths before 4 ns.

For each seed this simulates the scene (thrumapper-sim --seed; reused from OUT/SCENE-SEED/),
runs thrumapper-map's JADE on it (cli_map.map_survey without the fusion) and compares each
pose's paths with the specular echoes of the corridor walls' faces seen from the true pose
(bistatic.specular_path):

- leak dB: the simulator's TX leak over the data's energy (direct_leak.true_leak_db);
- spray: the share of JADE's path power before SPRAY_DELAY_S;
- per wall: the share of poses with a path within ANGLE_DEG of the echo's angle and
  DELAY_WINDOW_S of its delay, and the median and spread (median absolute deviation) of those
  paths' delay errors, ns.

The fusion does not use these delays as they are: it refits each wall's echo on the CSI
(docs/mapping.md). A wall JADE misses at a pose gets no refit there, and a path a nanosecond or
two off can be assigned to the wrong wall, which is where these figures matter.

Usage: benchmarks/corridor_echoes.py [--out DIR] [--scene office_floor] [--seeds own 1 2 ...]
       (PYTHONPATH=build/test_modules, or the module installed; about 30 s a seed)
"""
import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import json  # noqa: E402
import math  # noqa: E402
import sys  # noqa: E402

import numpy as np  # noqa: E402

from gnuradio.thrumapper import bistatic  # noqa: E402
from gnuradio.thrumapper import scene as scene_mod  # noqa: E402

import direct_leak  # noqa: E402
import office_surveys  # noqa: E402
from odometry_systematic import true_trajectory  # noqa: E402

#: a path counts as a wall's echo within this angle (deg) and this delay (s) of it
ANGLE_DEG = 25.0
DELAY_WINDOW_S = 4e-9
#: paths before this delay are the direct path's spray (it arrives at 2.3 ns on the trolley)
SPRAY_DELAY_S = 4e-9


def corridor_faces(truth_path):
    """{name: (point (2,), unit normal (2,) toward the corridor's axis)} of the truth's
    corridor_south and corridor_north faces (their longest piece)."""
    with open(truth_path, encoding="utf-8") as handle:
        features = json.load(handle)["features"]
    faces = {}
    for name in ("corridor_south", "corridor_north"):
        pieces = [np.array(f["geometry"]["coordinates"], float) for f in features
                  if f["properties"].get("kind") == "wall" and f["properties"].get("name") == name]
        if not pieces:
            raise RuntimeError(f"{truth_path}: no wall named {name}")
        piece = max(pieces, key=lambda c: np.hypot(*(c[-1] - c[0])))
        direction = (piece[-1] - piece[0]) / np.hypot(*(piece[-1] - piece[0]))
        normal = np.array([-direction[1], direction[0]])
        if normal @ (np.zeros(2) - piece[0]) < 0:  # toward the corridor's axis (y = 0)
            normal = -normal
        faces[name] = (piece[0], normal)
    return faces


def wall_figures(results, poses, face, tx_c, rx_c):
    """(share of poses with the wall's echo found, delay errors (s) of the paths found)."""
    point, normal = face
    errors = []
    for result, pose in zip(results, poses):
        aoa, delay, _ = bistatic.specular_path(bistatic.world_to_robot(point, pose),
                                               bistatic.rotate(normal, -pose[2]), tx_c, rx_c)
        near = [p["delay_s"] - delay for p in result[1]
                if abs(math.remainder(math.radians(p["aoa_deg"]) - aoa, 2 * math.pi)) < math.radians(ANGLE_DEG)
                and abs(p["delay_s"] - delay) < DELAY_WINDOW_S]
        if near:
            errors.append(min(near, key=abs))
    return len(errors) / len(results), np.array(errors)


def main(argv=None):
    parser = office_surveys.parser_for(__doc__, "out/corridor_echoes")
    args = parser.parse_args(argv)
    scene_path = office_surveys.scene_path(parser, args)
    print("| seed | TX leak dB | spray | south found | south delay error ns | north found | north delay error ns |")
    print("|---|---|---|---|---|---|---|")
    try:
        for seed in args.seeds:
            table_row(scene_path, args, seed)
    except RuntimeError as error:  # a scene without the corridor walls, a truth without poses
        print(f"corridor_echoes.py: {error}", file=sys.stderr)
        return 2
    return 0


def table_row(scene_path, args, seed):
    """Print the table's row of one seed."""
    _, info, truth_path = office_surveys.mapped(scene_path, args.scene, seed, args.out, build=False)
    scene = scene_mod.load_scene(scene_path, seed=None if seed == "own" else int(seed))
    refiner = info["fusion"].refiner
    results = info["jade_results"]
    poses = np.column_stack(true_trajectory(truth_path))
    if len(poses) != len(results):
        raise RuntimeError(f"{truth_path}: {len(poses)} true poses for {len(results)} pose groups")
    power = [(p["delay_s"] < SPRAY_DELAY_S, p["power"]) for r in results for p in r[1]]
    spray = sum(w for early, w in power if early) / max(sum(w for _, w in power), 1e-300)
    cells = []
    for name, face in corridor_faces(truth_path).items():
        found, errors = wall_figures(results, poses, face, refiner.tx_c, refiner.rx_c)
        if errors.size:
            median = float(np.median(errors))
            spread = float(np.median(np.abs(errors - median)))
            cells += [f"{100 * found:.0f} %", f"{median * 1e9:+.2f} ± {spread * 1e9:.2f}"]
        else:
            cells += ["0 %", "–"]
    print(f"| {seed} | {direct_leak.true_leak_db(refiner, scene):.1f} | {100 * spray:.0f} % | " +
          " | ".join(cells) + " |", flush=True)


if __name__ == "__main__":
    sys.exit(main())
