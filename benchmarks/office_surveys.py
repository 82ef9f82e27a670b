# SPDX-License-Identifier: GPL-3.0-or-later
"""What the benchmarks that map re-simulated example scenes share: their --out, --scene and
--seeds options, the scene simulated once per seed (thrumapper-sim --seed), reused after, and
its map as thrumapper-map makes it, which they map again from the same JADE results with one of
the fusion's constants changed."""
import argparse
import contextlib
import dataclasses
import io
import os

from gnuradio.thrumapper import cli_map, cli_sim
from gnuradio.thrumapper.survey import read_survey
from gnuradio.thrumapper.wall_fusion import FusionSettings, WallFusion

HERE = os.path.dirname(os.path.abspath(__file__))
SCENES_DIR = os.path.join(HERE, "..", "examples", "scenes")
# the office scenes' survey does not state its system delay, and the TX null hides the
# direct path it would be measured on (docs/mapping.md)
SYSTEM_DELAY_S = {"office_floor": 31e-9, "office_floor_drift": 31e-9}


def parser_for(doc, default_out):
    """An argument parser for a benchmark script whose docstring is `doc` (its first
    paragraph the description, the rest the epilog), with add_arguments' options."""
    parser = argparse.ArgumentParser(description=doc.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter,
                                     epilog="\n\n".join(doc.split("\n\n")[1:]))
    add_arguments(parser, default_out)
    return parser


def add_arguments(parser, default_out):
    parser.add_argument("--out", default=default_out, help="where the simulated surveys are kept")
    parser.add_argument("--scene", default="office_floor", help="example scene name (examples/scenes/NAME.yaml)")
    parser.add_argument("--seeds", nargs="+", default=["own", "1", "2", "3"],
                        help="seeds to simulate the scene with ('own': the scene's)")


def scene_path(parser, args):
    """The scene's YAML path, after checking --scene and --seeds (parser.error otherwise)."""
    path = os.path.join(SCENES_DIR, args.scene + ".yaml")
    if not os.path.exists(path):
        parser.error(f"--scene: no scene {path}")
    if any(seed != "own" and not seed.isdigit() for seed in args.seeds):
        parser.error(f"--seeds: expected 'own' or whole numbers, got {' '.join(args.seeds)}")
    return path


def simulated(path, scene, seed, out_root):
    """(SigMF meta path, truth GeoJSON path, seed number or None) of `scene` simulated with
    `seed` under out_root/SCENE-SEED/, simulating it only when it is not there yet."""
    number = None if seed == "own" else int(seed)
    out = os.path.join(out_root, f"{scene}-{seed}")
    meta = os.path.join(out, scene + ".sigmf-meta")
    truth = os.path.join(out, scene + ".truth.geojson")
    if not (os.path.exists(meta) and os.path.exists(truth)):
        with contextlib.redirect_stdout(io.StringIO()):
            cli_sim.main([path, "--out", out, "--quiet"] + ([] if number is None else ["--seed", str(number)]))
    return meta, truth, number


def mapped(path, scene, seed, out_root, build=True):
    """(FusedMap, cli_map.map_survey's info with the JADE results kept, truth GeoJSON path) of
    `scene` simulated with `seed` (simulated()) and mapped as thrumapper-map maps it (with
    build=False, JADE only: FusedMap None, for remapped())."""
    meta, truth, _ = simulated(path, scene, seed, out_root)
    fused, info = cli_map.map_survey(read_survey(meta), FusionSettings(material="plasterboard"), None,
                                     SYSTEM_DELAY_S.get(scene), keep_results=True, build=build)
    return fused, info, truth


def refilled(info, poses=None, first=None, settings=None, **constants):
    """A WallFusion given again the JADE results of the survey of `info` (mapped()), the first
    `first` pose groups only when given, at `poses` instead of the odometry's when given, with
    the FusionSettings fields in the dict `settings` changed and these WallFusion class
    constants set on the instance; its map not built yet."""
    fusion = info["fusion"]
    again = WallFusion(fusion.radar, dataclasses.replace(fusion.settings, **(settings or {})))
    for name, value in constants.items():
        if not hasattr(WallFusion, name):
            raise AttributeError(f"WallFusion has no constant {name}")
        setattr(again, name, value)
    again.enable_csi_refinement(info["system_delay_s"])
    for i, result in enumerate(info["jade_results"][:first]):
        again.add(result[0] if poses is None else poses[i], *result[1:])
    return again


def remapped(info, poses=None, first=None, settings=None, **constants):
    """refilled()'s map."""
    return refilled(info, poses, first, settings, **constants).build_map()
