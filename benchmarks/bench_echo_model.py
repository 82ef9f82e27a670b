#!/usr/bin/python3
# SPDX-License-Identifier: GPL-3.0-or-later
"""The wall echo model's speed: the C++ core (thrumapper.slab_echo) against numpy.

EchoModel.echo_csi, the CSI of one wall's echo per TX/RX element pair, is what the map's CSI
fits evaluate ~10^5 times a map. This prints, in one process:

1. per call, on the office radar (8 + 8 elements, 128 subcarriers, the survey's TX weights):
   echo_csi (C++) and echo_csi_reference (the same model in numpy, its first form), for a
   wall alone and for a wall behind another one, and the same for the double bounces
   (corner_csi, double_csi): their ratio and how far apart their results are (relative to
   the echo);
2. with --map: the office survey (simulated into --out, or reused from there: bench_map.py's
   directory) mapped three times by thrumapper-map's chain: as it is (the CSI fits' trial walls
   evaluated whole in C++, slab_echo.trial_energies), with the trials in Python around the
   C++ echo (CsiWallRefiner.USE_CORE_TRIALS off, the form before), and with the numpy echo
   forms swapped in too; each phase of the fusion timed, and how far apart the maps are.

Usage: benchmarks/bench_echo_model.py [--calls 2000] [--map] [--out out/bench_map]
"""
import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse  # noqa: E402
import contextlib  # noqa: E402
import io  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402

from gnuradio.thrumapper import building_sim, cli_map, cli_sim, scene, survey  # noqa: E402
from gnuradio.thrumapper.echo_model import EchoModel  # noqa: E402
from gnuradio.thrumapper.wall_refinement import CsiWallRefiner  # noqa: E402

HERE = os.path.dirname(os.path.abspath(__file__))
SCENE = os.path.join(HERE, "..", "examples", "scenes", "office_floor.yaml")
SYSTEM_DELAY_S = 31e-9  # the scene's (bench_map.py)


def per_call(calls):
    sc = scene.load_scene(SCENE)
    weights = building_sim.scene_tx_weights(sc)
    model = EchoModel(sc.radar.tx_elements_m, sc.radar.rx_elements_m, weights, sc.radar.carrier_hz,
                      sc.radar.subcarrier_offsets_hz)
    plaster = scene.MATERIAL_PRESETS["plasterboard"]
    rng = np.random.default_rng(7)
    # walls 1-4 m away on either side, turned up to 20°; the crossed one 1 m from the robot
    faces = [(np.array([rng.uniform(-1, 1), side * rng.uniform(1, 4)]),
              np.array([np.sin(np.radians(rng.uniform(-20, 20))), -side]))
             for side in rng.choice([-1.0, 1.0], size=64)]
    print(f"echo_csi per call: {model.tx_m.shape[0]} TX x {model.rx_m.shape[0]} RX elements, "
          f"{model.freqs_hz.size} subcarriers, {calls} calls each")
    print(f"{'case':28s}{'C++ us':>10s}{'numpy us':>10s}{'ratio':>8s}{'max rel. diff':>15s}")
    for name, crossed_of in (("a wall alone", lambda q, n: ()),
                             ("behind a corridor wall", lambda q, n: ((np.array([0.0, np.sign(q[1])]),
                                                                      -np.array([0.0, np.sign(q[1])]), plaster),))):
        seconds = {}
        for fn in (model.echo_csi, model.echo_csi_reference):  # the material's tables are made once
            fn(*faces[0], plaster, crossed_of(*faces[0]))
        for label, fn in (("cpp", model.echo_csi), ("numpy", model.echo_csi_reference)):
            started = time.perf_counter()
            for i in range(calls):
                q, n = faces[i % len(faces)]
                fn(q, n, plaster, crossed_of(q, n))
            seconds[label] = (time.perf_counter() - started) / calls
        diff = max(np.linalg.norm(model.echo_csi(q, n, plaster, crossed_of(q, n)) -
                                  model.echo_csi_reference(q, n, plaster, crossed_of(q, n))) /
                   np.linalg.norm(model.echo_csi_reference(q, n, plaster, crossed_of(q, n))) for q, n in faces)
        print(f"{name:28s}{seconds['cpp'] * 1e6:10.1f}{seconds['numpy'] * 1e6:10.1f}"
              f"{seconds['numpy'] / seconds['cpp']:7.1f}x{diff:15.1e}")
    # the double bounces: a room's inside corner 2-4 m away (end walls, room corners) and
    # the corridor's two walls answering each other (CsiWallRefiner.DOUBLE_BOUNCES)
    corners = [(np.array([rng.uniform(1, 4), -rng.uniform(1.5, 4)]), np.array([0.0, 1.0]), np.array([-1.0, 0.0]))
               for _ in range(16)]
    doubles = [(np.array([0.0, -rng.uniform(0.8, 1.5)]), np.array([0.0, 1.0]),
                np.array([0.0, rng.uniform(0.8, 1.5)]), np.array([0.0, -1.0])) for _ in range(16)]
    for name, cases, fast, slow in (("a room's corner", corners, model.corner_csi, model.corner_csi_reference),
                                    ("double bounce, corridor", doubles, model.double_csi,
                                     model.double_csi_reference)):
        seconds = {}
        for label, fn in (("cpp", fast), ("numpy", slow)):
            started = time.perf_counter()
            for i in range(calls):
                fn(*cases[i % len(cases)], plaster)
            seconds[label] = (time.perf_counter() - started) / calls
        diff = max(np.linalg.norm(fast(*c, plaster) - slow(*c, plaster)) / np.linalg.norm(slow(*c, plaster))
                   for c in cases)
        print(f"{name:28s}{seconds['cpp'] * 1e6:10.1f}{seconds['numpy'] * 1e6:10.1f}"
              f"{seconds['numpy'] / seconds['cpp']:7.1f}x{diff:15.1e}")


def map_office(out):
    meta = os.path.join(out, "office_floor.sigmf-meta")
    if not os.path.exists(meta):
        os.makedirs(out, exist_ok=True)
        with contextlib.redirect_stdout(io.StringIO()):
            cli_sim.main([SCENE, "--out", out, "--quiet"])
    runs = {}
    names = ("echo_csi", "double_csi", "corner_csi")
    fast = {name: getattr(EchoModel, name) for name in names}
    core_trials = CsiWallRefiner.USE_CORE_TRIALS
    for label in ("cpp", "trials", "numpy"):
        for name in names:
            setattr(EchoModel, name, getattr(EchoModel, name + "_reference") if label == "numpy" else fast[name])
        CsiWallRefiner.USE_CORE_TRIALS = label == "cpp"
        try:
            timings = {}
            fused, _ = cli_map.map_survey(survey.read_survey(meta), settings=cli_map.jade_settings(),
                                          system_delay_s=SYSTEM_DELAY_S, timings=timings)
        finally:
            for name in names:
                setattr(EchoModel, name, fast[name])
            CsiWallRefiner.USE_CORE_TRIALS = core_trials
        runs[label] = (timings, fused)
    poses = runs["cpp"][1].stats["poses"]
    print(f"\noffice_floor, {poses} poses: the fusion's phases, s (all C++ / trials in Python / numpy echo "
          f"too), and the ratios to the first")
    phases = runs["numpy"][1].stats.get("fusion_phases_s", {})
    for name in sorted(phases, key=lambda k: -phases[k]):
        a, b, c = (runs[label][1].stats["fusion_phases_s"].get(name, 0.0) for label in ("cpp", "trials", "numpy"))
        print(f"  {name:22s}{a:8.2f}{b:8.2f}{c:8.2f}{b / max(a, 1e-9):7.1f}x{c / max(a, 1e-9):6.1f}x")
    a, b, c = (runs[label][0]["fusion_s"] for label in ("cpp", "trials", "numpy"))
    print(f"  {'wall fusion':22s}{a:8.2f}{b:8.2f}{c:8.2f}{b / a:7.1f}x{c / a:6.1f}x   "
          f"({a / poses:.3f}, {b / poses:.3f}, {c / poses:.3f} s per pose)")
    worst = 0.0
    for label in ("trials", "numpy"):
        a, b = runs["cpp"][1], runs[label][1]
        same_walls = len(a.walls) == len(b.walls) and all(
            wa.cls == wb.cls for wa, wb in zip(a.walls, b.walls))
        ends = max((max(np.hypot(*(wa.start_m - wb.start_m)), np.hypot(*(wa.end_m - wb.end_m)))
                    for wa, wb in zip(a.walls, b.walls)), default=0.0) if same_walls else float("inf")
        track = float(np.max(np.abs(a.trajectory[:, :2] - b.trajectory[:, :2]))) if same_walls else float("inf")
        print(f"against the {label} run's map: {len(a.walls)} and {len(b.walls)} walls; wall ends at most "
              f"{ends:.1e} m apart, poses at most {track:.1e} m apart")
        worst = max(worst, ends, track)
    return 0 if worst < 1e-6 else 1


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--calls", type=int, default=2000, help="echo_csi calls timed per case")
    parser.add_argument("--map", action="store_true", help="also map the office survey three ways (~2 min)")
    parser.add_argument("--out", default="out/bench_map", help="where the simulated office survey is kept")
    args = parser.parse_args(argv)
    per_call(max(1, args.calls))
    return map_office(args.out) if args.map else 0


if __name__ == "__main__":
    sys.exit(main())
