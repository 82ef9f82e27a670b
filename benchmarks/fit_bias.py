#!/usr/bin/python3
# SPDX-License-Identifier: GPL-3.0-or-later
"""Which part of the simulated office biases the CSI echo fit of its corridor walls.

The CSI echo fit (docs/mapping.md, "The CSI echo fit") moves each mapped wall to where its
exact slab echo explains most of one pose's CSI. Given the TRUE walls and the TRUE poses it
should land on the true faces; what it does instead is what the echo model leaves out. This
simulates examples/scenes/office_floor.yaml and variants of it with one part of the scene
removed, and for each:

1. simulates the survey (thrumapper-sim, --quiet) into OUT/SEED/VARIANT/ (reused while the
   variant's scene, written there as office_floor.yaml, is unchanged);
2. calibrates the RX chains on the survey's reference frames and runs JADE on every pose
   group with its direct-path cancellation, as thrumapper-map does (system delay 31 ns, the
   scene's: the TX null hides the direct path it would be measured on);
3. gives a WallFusion's CsiWallRefiner the true map (every wall face of the truth file; the
   two corridor walls as one continuous plasterboard face each, hidden walls hidden) and the
   true poses, and fits each corridor wall at each pose alone (CsiWallRefiner.fit_echo);
4. turns each fit into its reflection point and prints how far it lies from the true face,
   in cm along the face's normal, positive toward the robot.

Per wall the table gives the RMS / mean over all the poses that see it; over the off-door
poses (the specular point not on a door leaf or the open gap of that wall); over the clean
poses (the specular point at least 0.45 m from every door of both walls; n of them); the mean
over the door poses (a wooden leaf is not the plasterboard the model assumes, an open door
leaves no face); and the longest run of consecutive off-door poses more than 3 cm off on
one side (poses, the specular points' x range, their mean). A bias the model misses shows as
a mean and a long run; noise as an RMS with neither.

Last column, the survey's direct-path leak: the TX chains' errors leave part of the direct
path in the data after the cancellation of the nominal one. Measured on a survey of the
variant's radio with the direct path alone and no noise (JADE's input energy), against the
corridor walls' echoes alone (ideal radio, first-order paths, no noise), in dB; "none" when
nothing is left (no TX errors).

Variants (--variants, comma-separated; default all):
  full                         the scene as it is
  no_clutter                   no desks, cabinets, radiator, person
  no_doors                     corridor walls without doors
  ideal_radio                  no radio impairment at all (system delay stated, no chain
                               errors, no DC offset, no reference frames)
  no_tx_errors                 the scene's radio but exact TX chains
  ideal_radio_no_second_order  ideal radio, first-order paths only (physics: second_order)
  doors_open                   every door an open gap (the scene's radio)

--doubles models the corridor's double bounces in the fits (CsiWallRefiner.DOUBLE_BOUNCES =
"coherent"; exact on a true map); --leak estimates the direct path's leak on the survey
(CsiWallRefiner.estimate_direct_leak) before the fits and models it, printed as "fitted
leak". Measured with both and what they change: docs/mapping.md, "Two errors of the echo
model".

Usage: benchmarks/fit_bias.py [--out DIR] [--seed N] [--variants full,no_doors,...] [--doubles] [--leak]
       (PYTHONPATH=build/test_modules, or the module installed)
"""
import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse  # noqa: E402
import collections  # noqa: E402
import contextlib  # noqa: E402
import copy  # noqa: E402
import functools  # noqa: E402
import io  # noqa: E402
import json  # noqa: E402
import math  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402
import yaml  # noqa: E402

from gnuradio.thrumapper import bistatic, cli_map, cli_sim, jade_pipeline, rx_calibration  # noqa: E402
from gnuradio.thrumapper.survey import read_survey  # noqa: E402
from gnuradio.thrumapper.wall_fusion import FusionSettings, RadarGeometry, WallFusion  # noqa: E402

HERE = os.path.dirname(os.path.abspath(__file__))
SCENE = os.path.join(HERE, "..", "examples", "scenes", "office_floor.yaml")
SYSTEM_DELAY_S = 31e-9  # the scene's; the nulled survey cannot measure it (docs/mapping.md)
CORRIDOR = ("corridor_south", "corridor_north")
CLEAN_M = 0.45  # a clean pose's specular point is at least this far from every door
RUN_CM = 3.0  # a run counts poses more than this off the face, on one side
# one pose's fit of a corridor wall: its specular point's x, how far off the face (+ toward the
# robot), whether that point is on a door of that wall, within CLEAN_M of a door of either
Fit = collections.namedtuple("Fit", "x_m error_cm on_door near_door")
NO_PATHS_BUT_DIRECT = {"reflections": False, "second_order": False, "diffuse": False, "edges": False,
                       "clutter": False}


def _ideal_radio(s):
    # the delay stays (the fits are told it), stated in the survey; no chain error, no DC
    s["impairments"] = {"system_delay_s": s["impairments"]["system_delay_s"], "system_delay_known": True}


def _no_tx_errors(s):
    s["impairments"].pop("tx")


def _first_order_only(s):
    _ideal_radio(s)
    s.setdefault("physics", {})["second_order"] = False


def _doors_open(s):
    for door in s["doors"]:
        door.pop("material", None)  # a door without a leaf is a gap (docs/simulator.md)


VARIANTS = {
    "full": lambda s: None,
    "no_clutter": lambda s: s.pop("clutter"),
    "no_doors": lambda s: s.pop("doors"),
    "ideal_radio": _ideal_radio,
    "no_tx_errors": _no_tx_errors,
    "ideal_radio_no_second_order": _first_order_only,
    "doors_open": _doors_open,
}


def corridor_reference(base):
    """The corridor walls' echoes alone: the leak level's yardstick."""
    s = copy.deepcopy(base)
    s["walls"] = [w for w in s["walls"] if w["name"] in CORRIDOR]
    for key in ("doors", "clutter"):
        s.pop(key, None)
    _ideal_radio(s)
    s["noise"] = "none"
    s["physics"] = {"second_order": False, "diffuse": False, "edges": False, "clutter": False}
    return s


def direct_only(scene):
    """The scene's radio with its direct path alone and no noise: what the cancellation leaves."""
    s = copy.deepcopy(scene)
    s["noise"] = "none"
    s["physics"] = dict(NO_PATHS_BUT_DIRECT)
    return s


def simulated(scene, folder, seed):
    """(survey meta, truth) of `scene` (a scene dict) simulated into folder, reused while the
    scene written there is the same."""
    os.makedirs(folder, exist_ok=True)
    text = yaml.safe_dump(scene, sort_keys=False, default_flow_style=None)
    scene_path = os.path.join(folder, scene["name"] + ".yaml")
    meta = os.path.join(folder, scene["name"] + ".sigmf-meta")
    truth = os.path.join(folder, scene["name"] + ".truth.geojson")
    if os.path.exists(meta) and os.path.exists(truth) and os.path.exists(scene_path):
        with open(scene_path, encoding="utf-8") as handle:
            if handle.read() == text:
                return meta, truth
    with open(scene_path, "w", encoding="utf-8") as handle:
        handle.write(text)
    argv = [scene_path, "--out", folder, "--quiet"] + ([] if seed is None else ["--seed", str(seed)])
    err = io.StringIO()
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(err):
        code = cli_sim.main(argv)
    if code != 0:
        raise RuntimeError(f"thrumapper-sim {' '.join(argv)} failed: {err.getvalue().strip()}")
    return meta, truth


def jade_input(meta, system_delay_s=SYSTEM_DELAY_S):
    """(survey, the fusion's input per pose group: pose, paths, frame, CSI as JADE saw it with
    the direct path cancelled, TX weights; the system delay used), as thrumapper-map makes
    them, at system_delay_s (None: the survey's, measured on the direct path when it states
    none)."""
    survey = read_survey(meta)
    work = rx_calibration.calibrated_survey(survey, rx_calibration.calibrate_survey(survey))
    if system_delay_s is None:
        system_delay_s = survey.system_delay_s
    if system_delay_s is None:
        system_delay_s = jade_pipeline.estimate_system_delay(work, jade_pipeline.group_frames_by_pose(work))
    items = [(r["pose"], r["paths"], r["frames"][0], r["csi"], r["tx_weights"])
             for r in jade_pipeline.run_survey(work, cli_map.jade_settings(), system_delay_s, keep_csi=True)]
    return survey, items, system_delay_s


def csi_energy(items):
    """Mean energy of a frame of JADE's input, over the poses."""
    return float(np.mean([np.mean(np.sum(np.abs(csi) ** 2, axis=(1, 2))) for _, _, _, csi, _ in items]))


def face(p0, p1, normal):
    """A refiner wall dict (world) of the face from p0 to p1 whose normal points to `normal`'s side."""
    p0, p1 = np.asarray(p0, float), np.asarray(p1, float)
    normal = np.asarray(normal, float) / np.hypot(*normal)
    direction = np.array([-normal[1], normal[0]])
    centre = 0.5 * (p0 + p1)
    ts = sorted(float((p - centre) @ direction) for p in (p0, p1))
    return {"centre": centre, "normal": normal, "direction": direction, "t0": ts[0], "t1": ts[1]}


def true_map(truth, scene):
    """(walls, hidden) of the truth: each corridor wall one continuous face over its pieces'
    extent (door leaves and gaps included: the fit's model is plasterboard throughout), then
    every other wall's faces, the pieces of a face merged; end walls line of sight, the rest
    hidden."""
    centre_lines = {w["name"]: np.asarray(w["segment"], float) for w in scene["walls"]}
    corridor_x = {name: [] for name in CORRIDOR}
    corridor_y = {}
    faces = {}  # (wall name, face offset, normal) -> points, normal, direction
    for f in truth["features"]:
        p = f["properties"]
        if p.get("kind") != "wall" or p.get("door"):
            continue
        points = np.asarray(f["geometry"]["coordinates"], float)
        if p["name"] in CORRIDOR:
            corridor_x[p["name"]] += points[:, 0].tolist()
            corridor_y[p["name"]] = float(points[0, 1])
            continue
        start, end = centre_lines[p["name"]]
        direction = (end - start) / np.hypot(*(end - start))
        normal = np.array([-direction[1], direction[0]])
        offset = float((points[0] - start) @ normal)
        if offset < 0:  # the face on the other side of the centre line
            normal, offset = -normal, -offset
        key = (p["name"], round(offset, 4), round(float(normal[0]), 3), round(float(normal[1]), 3))
        faces.setdefault(key, {"points": [], "normal": normal, "direction": direction})["points"] += points.tolist()
    walls = [face([min(corridor_x[n]), corridor_y[n]], [max(corridor_x[n]), corridor_y[n]],
                  [0.0, -np.sign(corridor_y[n])]) for n in CORRIDOR]
    hidden = [False, False]
    for (name, *_), v in sorted(faces.items(), key=lambda kv: kv[0][0]):
        points = np.asarray(v["points"])
        along = points @ v["direction"]
        walls.append(face(points[np.argmin(along)], points[np.argmax(along)], v["normal"]))
        hidden.append(not name.startswith("end_"))
    return walls, hidden


def doors(truth):
    """{corridor wall: [(x0, x1)]} of its door leaves and open doors (gaps between its pieces)."""
    out = {name: [] for name in CORRIDOR}
    pieces = {name: [] for name in CORRIDOR}
    for f in truth["features"]:
        p = f["properties"]
        if p.get("kind") != "wall" or p["name"] not in CORRIDOR:
            continue
        xs = sorted(c[0] for c in f["geometry"]["coordinates"])
        (out if p.get("door") else pieces)[p["name"]].append((xs[0], xs[1]))
    for name in CORRIDOR:
        spans = sorted(pieces[name] + out[name])
        out[name] += [(a1, b0) for (_, a1), (b0, _) in zip(spans, spans[1:]) if b0 - a1 > 0.05]
    return out


def fit_errors(survey, items, truth_path, scene, doubles, leak):
    """{corridor wall: [Fit of each pose that sees it]}, and the fitted leak in dB (None
    without `leak`)."""
    with open(truth_path, encoding="utf-8") as handle:
        truth = json.load(handle)
    settings = FusionSettings()
    if survey.wall_model is not None:  # the simulated survey states its walls' material
        settings.material = dict(survey.wall_model)
        settings.estimate_materials = False
    fusion = WallFusion(RadarGeometry.from_survey(survey), settings)
    fusion.enable_csi_refinement(SYSTEM_DELAY_S)
    for item in items:
        fusion.add(*item)
    trajectory = next(f for f in truth["features"] if f["properties"].get("kind") == "trajectory")
    poses = np.column_stack([np.asarray(trajectory["geometry"]["coordinates"], float),
                             trajectory["properties"]["headings_rad"]])
    if len(poses) != len(fusion.groups):
        raise RuntimeError(f"{len(fusion.groups)} pose groups in the survey, {len(poses)} true poses")
    walls, hidden = true_map(truth, scene)
    refiner = fusion.refiner
    refiner.DOUBLE_BOUNCES = "coherent" if doubles else False
    refiner.set_map(walls, poses, [[(q["aoa_rad"], q["delay_s"]) for q in g.paths] for g in fusion.groups], hidden)
    leak_db = refiner.estimate_direct_leak() if leak else None
    spans = doors(truth)
    fits = {}
    for k, name in enumerate(CORRIDOR):
        wall, fits[name] = walls[k], []
        for g, pose in enumerate(poses):
            echo = refiner.fit_echo(g, k)  # (aoa_rad, delay_s) of the fitted wall's specular path
            if echo is None:
                continue
            x_m = float(refiner._pivot(wall, pose)[0])  # there is one: the pose sees the wall
            point, _ = bistatic.reflection_point(np.array([echo[0]]), np.array([echo[1]]), fusion.tx_c, fusion.rx_c)
            error_cm = 100.0 * float((bistatic.robot_to_world(point[0], pose) - wall["centre"]) @ wall["normal"])
            fits[name].append(Fit(x_m, error_cm, any(a <= x_m <= b for a, b in spans[name]),
                                  any(a - CLEAN_M <= x_m <= b + CLEAN_M for n in CORRIDOR for a, b in spans[n])))
    return fits, leak_db


def longest_run(fits):
    """(poses, x0 m, x1 m, mean cm) of the longest run of consecutive fits more than RUN_CM
    off on one side; poses 0 when there is none."""
    best, run, side = (0, None, None, 0.0), [], 0
    for fit in fits + [None]:  # (None ends the last run)
        s = 0 if fit is None or abs(fit.error_cm) <= RUN_CM else (1 if fit.error_cm > 0 else -1)
        if s != 0 and s == side:
            run.append(fit)
            continue
        if len(run) > best[0]:
            best = (len(run), run[0].x_m, run[-1].x_m, float(np.mean([f.error_cm for f in run])))
        run, side = ([fit] if s else []), s
    return best


def rms_mean(fits):
    if not fits:
        return "–"
    e_cm = np.array([f.error_cm for f in fits])
    return f"{math.sqrt(np.mean(e_cm ** 2)):.1f} / {e_cm.mean():+.1f}"


def wall_cells(fits):
    """The table's cells of one wall."""
    off_door = [f for f in fits if not f.on_door]
    on_door = [f.error_cm for f in fits if f.on_door]
    clean = [f for f in fits if not f.near_door]
    poses, x0_m, x1_m, mean_cm = longest_run(off_door)
    return [str(len(fits)), rms_mean(fits), rms_mean(off_door), f"{rms_mean(clean)} ({len(clean)})",
            f"{np.mean(on_door):+.1f}" if on_door else "–",
            f"{poses} poses, x {x0_m:.1f}–{x1_m:.1f} m ({mean_cm:+.0f})" if poses else "–"]


def fmt_db(value):
    return "–" if value is None else ("none" if value == -math.inf else f"{value:+.1f} dB")


@functools.lru_cache(maxsize=None)
def corridor_echo_energy(root, seed):
    """The leak level's yardstick, simulated once into ROOT/corridor_reference."""
    with open(SCENE, encoding="utf-8") as handle:
        meta, _ = simulated(corridor_reference(yaml.safe_load(handle)), os.path.join(root, "corridor_reference"), seed)
    return csi_energy(jade_input(meta)[1])


def leak_level_db(scene, folder, root, seed):
    meta, _ = simulated(direct_only(scene), os.path.join(folder, "direct_only"), seed)
    energy, reference = csi_energy(jade_input(meta)[1]), corridor_echo_energy(root, seed)
    # exact TX chains leave the survey's rounding only: about -130 dB
    return 10.0 * math.log10(energy / reference) if energy > 1e-9 * reference else -math.inf


HEADER = ["variant", "wall", "poses fitted", "all RMS / mean", "off-door RMS / mean", "clean RMS / mean (n)",
          "door poses mean", "longest run > 3 cm, off-door", "direct-path leak / corridor echoes"]


def variant_rows(name, base, root, args):
    """The table's rows of one variant, one per corridor wall; a progress line on stderr."""
    started = time.perf_counter()
    folder = os.path.join(root, name)
    scene = copy.deepcopy(base)
    VARIANTS[name](scene)
    meta, truth = simulated(scene, folder, args.seed)
    survey, items, _ = jade_input(meta)
    jade_s = time.perf_counter() - started
    fits, fitted_leak_db = fit_errors(survey, items, truth, scene, args.doubles, args.leak)
    fits_s = time.perf_counter() - started - jade_s
    leak_db = leak_level_db(scene, folder, root, args.seed)
    print(f"{name}: survey and JADE {jade_s:.0f} s, fits {fits_s:.0f} s, in all {time.perf_counter() - started:.0f} s",
          file=sys.stderr, flush=True)
    return [[name, wall.split("_")[1]] + wall_cells(fits[wall]) + [fmt_db(leak_db)] +
            ([fmt_db(fitted_leak_db)] if args.leak else []) for wall in CORRIDOR]


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     epilog=__doc__.split("\n\n", 1)[1],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", default="out/fit_bias",
                        help="where the simulated surveys are kept (OUT/own/VARIANT/ or OUT/seed-N/VARIANT/) "
                             "and reused; default %(default)s")
    parser.add_argument("--seed", type=int, default=None,
                        help="simulate with this seed (thrumapper-sim --seed: other noise, chain errors, "
                             "diffuse scatterers, the same building); default the scene's own (2024)")
    parser.add_argument("--variants", default=",".join(VARIANTS),
                        help=f"comma-separated, of: {', '.join(VARIANTS)}; default all")
    parser.add_argument("--doubles", action="store_true",
                        help="model the double bounces between the corridor walls in the fits "
                             "(CsiWallRefiner.DOUBLE_BOUNCES = \"coherent\")")
    parser.add_argument("--leak", action="store_true",
                        help="estimate the direct path's leak on each survey and model it in the fits "
                             "(CsiWallRefiner.estimate_direct_leak)")
    args = parser.parse_args(argv)
    names = [n.strip() for n in args.variants.split(",") if n.strip()]
    unknown = [n for n in names if n not in VARIANTS]
    if unknown or not names:
        parser.error(f"unknown variants {unknown}; known: {', '.join(VARIANTS)}")
    with open(SCENE, encoding="utf-8") as handle:
        base = yaml.safe_load(handle)
    root = os.path.join(args.out, "own" if args.seed is None else f"seed-{args.seed}")
    header = HEADER + (["fitted leak"] if args.leak else [])
    table = []
    for name in names:
        try:
            table += variant_rows(name, base, root, args)
        except Exception as error:  # one variant's failure is reported; the others still run
            print(f"fit_bias: {name} failed: {type(error).__name__}: {error}", file=sys.stderr, flush=True)
            table.append([name, f"failed: {type(error).__name__}"] + [""] * (len(header) - 2))
    models = " + ".join(m for m, on in (("double bounces", args.doubles), ("fitted leak", args.leak)) if on)
    print(f"office_floor, seed {'own' if args.seed is None else args.seed}: the corridor walls fitted pose by pose "
          f"on the true map from the true poses ({models or 'the default echo model'}); cm, + toward the robot")
    for row in [header, ["---"] * len(header)] + table:
        print("| " + " | ".join(row) + " |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
