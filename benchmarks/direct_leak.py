#!/usr/bin/python3
# SPDX-License-Identifier: GPL-3.0-or-later
"""The direct path the TX chains' errors leave: the simulator's against the fusion's estimate.

The survey calibrates the RX chains only. Each TX chain's small gain and phase error a_k fills
the null the TX weights steer toward the RX, and cancelling the nominal direct path leaves
sum_k w_k (a_k - 1) d_k in the data (d_k: element k's direct path), the same at every pose.
The fusion estimates it on its first map (CsiWallRefiner.estimate_direct_leak) and models it in
the CSI fits only where the estimate holds at least WallFusion.DIRECT_LEAK_MIN_DB of the data
and the track is at least WallFusion.DIRECT_LEAK_MIN_TRACK_M long (docs/mapping.md, "The
direct path's leak, where it is strong").

For each seed this simulates the scene (thrumapper-sim --seed; reused from OUT/SCENE-SEED/),
maps it as thrumapper-map does with its default options (cli_map.map_survey) and prints, in
dB of the data's energy:

- truth: the leak the simulator's drawn TX chain gains leave, computed from the scene's
  impairments and the refiner's element direct paths, less its part along the nominal path;
- estimate: the fusion's (stats direct_leak_db), and whether the fits model it;
- first N m: the estimate a map of the track's first N metres alone makes (what a live map
  makes early in a survey; --spans), with the minimum track length lifted for it: how much of
  the corridor walls' echo a short track takes for leak.

Usage: benchmarks/direct_leak.py [--out DIR] [--scene office_floor] [--seeds own 1 2 ...] [--spans 2 4 8]
       (PYTHONPATH=build/test_modules, or the module installed; a few minutes a seed)
"""
import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse  # noqa: E402
import math  # noqa: E402
import sys  # noqa: E402

import numpy as np  # noqa: E402

from gnuradio.thrumapper import building_sim  # noqa: E402
from gnuradio.thrumapper import scene as scene_mod  # noqa: E402
from gnuradio.thrumapper.wall_fusion import WallFusion, _path_length  # noqa: E402

import office_surveys  # noqa: E402


def true_leak_db(refiner, scene):
    """The simulator's leak over the data's energy, dB, on the refiner's pose groups."""
    directs = refiner._element_directs()  # (M*N, K), unit TX weight each
    alpha = building_sim.chain_gains(scene.impairments["tx"], refiner.freqs_hz)  # (K, N)
    k, n = alpha.shape
    m = directs.shape[0] // n
    per_element = directs.reshape(m, n, k)
    leak_energy = data_energy = 0.0
    for data in refiner.poses.values():
        leak = np.einsum("mnk,k,kn->mn", per_element, data.model.weights, alpha - 1.0).ravel()
        unit = data.direct / np.linalg.norm(data.direct)
        leak = leak - unit * np.vdot(unit, leak)
        leak_energy += float(np.vdot(leak, leak).real) * data.rows.shape[0]
        data_energy += float(np.sum(np.abs(data.rows) ** 2))
    return 10.0 * math.log10(leak_energy / data_energy) if leak_energy > 0 else -math.inf


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter,
                                     epilog="\n\n".join(__doc__.split("\n\n")[1:]))
    office_surveys.add_arguments(parser, "out/direct_leak")
    parser.add_argument("--spans", nargs="*", type=float, default=[2.0, 4.0, 8.0],
                        help="also estimate over the track's first N metres only")
    args = parser.parse_args(argv)
    scene_path = office_surveys.scene_path(parser, args)
    spans = sorted(set(args.spans))
    print(f"| seed | truth dB | estimate dB | modelled | " + " | ".join(f"first {s:g} m" for s in spans) + " |")
    print("|---|---|---|---|" + "---|" * len(spans))
    for seed in args.seeds:
        fused, info, _ = office_surveys.mapped(scene_path, args.scene, seed, args.out)
        scene = scene_mod.load_scene(scene_path, seed=None if seed == "own" else int(seed))
        truth = true_leak_db(info["fusion"].refiner, scene)
        estimate = fused.stats.get("direct_leak_db")
        modelled = fused.stats.get("direct_leak_modelled", False)
        travelled = _path_length(np.array([r[0] for r in info["jade_results"]], float))
        counts = [int(np.count_nonzero(travelled <= span + 1e-9)) for span in spans]
        # a map of the first pose groups alone, at any length
        firsts = [office_surveys.remapped(info, first=count, DIRECT_LEAK_MIN_TRACK_M=0.0).stats.get("direct_leak_db")
                  if count >= 2 else None for count in counts]

        def db(value):
            return "–" if value is None else f"{value:.1f}"

        print(f"| {seed} | {db(truth)} | {db(estimate)} | {'yes' if modelled else 'no'} | " +
              " | ".join(db(v) for v in firsts) + " |", flush=True)
    print(f"\nmodelled where the estimate is at least {WallFusion.DIRECT_LEAK_MIN_DB:g} dB on a track of at least "
          f"{WallFusion.DIRECT_LEAK_MIN_TRACK_M:g} m", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
