#
# SPDX-License-Identifier: GPL-3.0-or-later
#
"""thrumapper-sim: simulate a survey of a scene and write it as SigMF with its ground truth."""

import argparse
import json
import math
import os
import sys

import numpy as np

EPILOG = """\
what it writes (NAME is the scene's name, or --name):
  DIR/NAME.sigmf-meta, DIR/NAME.sigmf-data
      the CSI survey (FORMATS.md, thrumapper:kind "csi"): one capture per frame, the poses
      as the robot's odometry reports them (with the scene's odometry error), RX reference
      frames first when the scene's RX chains are impaired.
  DIR/NAME.truth.geojson
      the ground-truth map: the wall faces seen from the true trajectory (line_of_sight or
      hidden), the corners, the true trajectory. Score a map against it with thrumapper-eval.

examples:
  thrumapper-sim examples/scenes/office_floor.yaml --out /tmp/survey
  thrumapper-sim examples/scenes/paper_4_3_hidden_1p5m.yaml --out /tmp/s --seed 7 --quiet
  thrumapper-sim my_scene.yaml --check          # validate the scene, print a summary, stop
  thrumapper-sim examples/scenes/office_floor.yaml --out /tmp/s --tx-calibration-frames 4
      # the radio's TX calibration first: single-element frames at the first poses, the survey
      # sent with the corrected weights (thrumapper-beam --tx-calibration reads them back)

The scene format (YAML, SI units) and the physics are described in docs/simulator.md; the
scenes of the paper's experiments are in examples/scenes/.
"""


def _parser():
    parser = argparse.ArgumentParser(
        prog="thrumapper-sim",
        description="Simulate a bistatic OFDM array radar survey of a building described by a YAML\n"
                    "scene: walls (dielectric slabs, doors), clutter, a trajectory, the radar and its\n"
                    "impairments. Writes the CSI survey (SigMF) and the ground-truth map (GeoJSON).",
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("scene", metavar="SCENE.yaml", help="the scene to simulate")
    parser.add_argument("--out", metavar="DIR", default=".",
                        help="directory for the outputs, created if missing (default: the current one)")
    parser.add_argument("--name", help="base name of the outputs (default: the scene's name)")
    parser.add_argument("--seed", type=int,
                        help="override the scene's seed (diffuse scatterers, impairments, noise, odometry)")
    parser.add_argument("--tx-calibration-frames", type=int, metavar="F",
                        help="calibrate the TX chains before the survey, F frames per element at each of the first "
                             "poses (the scene's impairments.tx_calibration_frames; docs/simulator.md)")
    parser.add_argument("--quiet", action="store_true", help="no progress bar, print only the written files")
    parser.add_argument("--check", action="store_true", help="validate the scene and print a summary; write nothing")
    return parser


def main(argv=None) -> int:
    args = _parser().parse_args(argv)
    from . import building_sim
    from . import scene as scene_mod

    try:
        scene = scene_mod.load_scene(args.scene, seed=args.seed)
        if args.tx_calibration_frames is not None:
            if args.tx_calibration_frames < 0:
                raise scene_mod.SceneError(f"--tx-calibration-frames: expected 0 or more, got {args.tx_calibration_frames}")
            scene.impairments["tx_calibration_frames"] = args.tx_calibration_frames
    except scene_mod.SceneError as err:
        text = str(err) if str(err).startswith(args.scene) else f"{args.scene}: {err}"
        print(f"thrumapper-sim: error: {text}", file=sys.stderr)
        return 2
    if args.check:
        print(scene_mod.describe(scene))
        return 0
    if not args.quiet:
        print(scene_mod.describe(scene))

    from .survey import write_survey

    name = args.name or scene.name
    os.makedirs(args.out, exist_ok=True)
    base = os.path.join(args.out, name)
    result = building_sim.simulate_survey(scene, progress=not args.quiet)
    system_delay_s = result.system_delay_s if result.system_delay_known else None
    meta_path = write_survey(
        base,
        result.csi,
        subcarrier_offsets_hz=result.subcarrier_offsets_hz,
        center_frequency_hz=result.center_frequency_hz,
        rx_elements_m=result.rx_elements_m,
        tx_elements_m=result.tx_elements_m,
        tx_weights=result.tx_weights,
        poses=result.poses_odometry,
        frame_types=result.frame_types,
        frame_tx_weights=result.frame_tx_weights,
        system_delay_s=system_delay_s,
        wall_model=result.wall_model,
        datetimes=result.datetimes,
        description=scene.description or f"simulated survey of scene {scene.name}",
        author="thrumapper-sim",
        extra_global={"thrumapper:simulated_scene": {"name": scene.name, "seed": scene.seed}},
    )
    truth_path = base + ".truth.geojson"
    with open(truth_path, "w", encoding="utf-8") as handle:
        json.dump(building_sim.truth_geojson(scene), handle, indent=1)
        handle.write("\n")
    data_path = meta_path[: -len(".sigmf-meta")] + ".sigmf-data"
    print(meta_path)
    print(data_path)
    print(truth_path)
    if not args.quiet:
        survey_frames = result.frame_types.count("survey")
        print(f"{result.csi.shape[0]} frames ({result.csi.shape[0] - survey_frames} rx_reference, {survey_frames} "
              f"survey) of M={result.csi.shape[1]} x N={result.csi.shape[2]} in {result.elapsed_s:.2f} s; "
              f"noise {10 * math.log10(max(result.noise_power, 1e-300)):.1f} dB per sample")
        if result.tx_calibration is not None:
            from . import tx_calibration

            cal = result.tx_calibration
            left = np.angle(result.tx_chain_residual[:, result.subcarrier_offsets_hz.size // 2])
            freqs = result.center_frequency_hz + result.subcarrier_offsets_hz
            depth = [tx_calibration.null_depth_db(result.tx_weights, result.tx_elements_m, result.rx_elements_m, freqs,
                                                  chains) for chains in (result.tx_chain_gains, result.tx_chain_residual)]
            print(f"{cal.summary()}; TX phase errors left {math.degrees(np.std(left - np.mean(left))):.2f} deg rms; "
                  f"null at the receiver {depth[0]:.1f} dB before, {depth[1]:.1f} dB after")
    return 0


if __name__ == "__main__":
    sys.exit(main())
