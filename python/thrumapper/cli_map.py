#
# SPDX-License-Identifier: GPL-3.0-or-later
#
"""thrumapper-map: a CSI survey in, a floor plan out (GeoJSON, PNG, ROS map)."""

import argparse
import dataclasses
import json
import math
import sys
import time

EPILOG = """\
the chain (docs/mapping.md):
  1. RX chains calibrated from the survey's rx_reference frames (relative gain, phase and
     delay per channel, the DC offset), when it has them;
  2. the system delay: --system-delay-s, else the survey's thrumapper:system_delay_s, else
     measured on the direct TX->RX path (impossible when the TX null hides it: then give it);
  3. JADE on every pose group (thrumapper-jade's code; successive cancellation with
     --stages when the estimator has it);
  4. wall fusion: reflection points and orientations, corners, ghosts, walls, classes, pose
     correction; each echo of a mapped wall replaced by that wall fitted on its pose's CSI with
     the exact slab echo model of the wall material (the survey's thrumapper:wall_model, else
     --material; --no-csi-refinement: JADE's echoes with the slab model's shift instead, as the
     GNU Radio block wall_fusion does when JADE Estimator does not attach the CSI); a wall
     across the corridor behind the start, ranged on every pose's CSI, holds the distance
     travelled (the odometry's scale) where there is one (stats: axial_landmarks,
     odometry_scale), and the lean of the fitted walls' orientations that the corridor's
     double bounces give is estimated with the poses (--no-orientation-lean; stats:
     orientation_lean_deg);
  5. walls JADE does not report, found on the CSI alone: end walls across the track past its
     ends, and side walls across the track from a line-of-sight wall where an echo of the
     same delay hid them (--no-side-walls; stats: end_walls, side_walls; GeoJSON "source");
  6. open doorways, on the CSI: where a line-of-sight wall's echo is missing between
     stretches that hold it, the wall is drawn with a gap (stats: openings); a room's back
     wall seen through one is line of sight up to its partitions;
  7. partitions between the rooms behind a wall, on the CSI: where the hidden wall's echo
     vanishes beside one (one leg runs along it) over two poses, or over one where it is
     deep or a room's corner answers there (--no-partitions; stats: partitions; GeoJSON
     "source": "partition");
  8. hidden walls drawn on past their echoes, on the CSI: JADE reports few echoes of the
     rooms' back walls, and a hidden wall goes on along its line as far as the poses beside
     it hold its echo (--no-hidden-continuation; stats: hidden_walls_continued; GeoJSON
     "source": "continued");
  9. the plan squared, last: walls within 5 deg of the map's main direction or of square to
     it turned onto it, and the pieces of one wall put on one line (--no-square-plan; stats:
     walls_squared, walls_on_shared_lines).

outputs:
  MAP.geojson  FORMATS.md's map: walls (class, confidence, material), detections, corners,
               trajectory, and open doorways ("kind": "opening", which thrumapper-eval scores)
  MAP.png      the map with the trajectory and the detections (matplotlib)
  PREFIX.pgm, PREFIX.yaml   a ROS map_server occupancy grid (--ros-resolution m/pixel)

examples:
  thrumapper-sim examples/scenes/paper_4_4_corridor_corner.yaml --out out/
  thrumapper-map out/paper_4_4_corridor_corner.sigmf-meta --geojson out/map.geojson --png out/map.png
  thrumapper-eval out/map.geojson out/paper_4_4_corridor_corner.truth.geojson
  thrumapper-map office.sigmf-meta --geojson office.geojson --system-delay-s 31e-9 --ros-map office

exit status: 0 done, 2 bad input (the message names it).
"""


def build_parser():
    p = argparse.ArgumentParser(
        prog="thrumapper-map",
        description="Map the walls of a building from a CSI survey (SigMF, thrumapper:kind \"csi\"): "
                    "calibration, JADE and wall fusion, the same code as the GNU Radio flowgraph.",
        epilog=EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("survey", help="the survey: NAME.sigmf-meta (or NAME, or NAME.sigmf-data)")
    p.add_argument("--geojson", required=True, metavar="MAP.geojson", help="write the map here (FORMATS.md)")
    p.add_argument("--png", metavar="MAP.png", help="write a picture of the map")
    p.add_argument("--ros-map", metavar="PREFIX", help="write PREFIX.pgm and PREFIX.yaml (ROS map_server)")
    p.add_argument("--ros-resolution", type=float, default=0.05, metavar="M", help="ROS map pixel size (default 0.05 m)")
    p.add_argument("--truth", metavar="TRUTH.geojson", help="draw this map faintly under the PNG (e.g. thrumapper-sim's truth)")
    p.add_argument("--system-delay-s", type=float, metavar="S", help="the system delay, overriding the survey's")
    p.add_argument("--material", default=None, metavar="NAME",
                   help="wall material for the slab correction when the survey has no thrumapper:wall_model: "
                        "plasterboard (default), stud_wall, brick, concrete, glass, wood, metal, or none")
    p.add_argument("--no-material-corrections", action="store_true",
                   help="keep walls labelled brick or concrete where the survey material's echo model fits "
                        "them (by default each is moved by what its own material's model changes in its CSI fit: "
                        "0.18-0.30 m inward on the office floors' hidden exterior walls, 0.2-0.3 m on skewed_walls' "
                        "line-of-sight brick wall; a line-of-sight wall only when labelled against walls facing its "
                        "way; stats: material_corrections_m)")
    p.add_argument("--no-side-walls", action="store_true",
                   help="do not search the CSI for walls across the track from the line-of-sight walls where JADE "
                        "reports none (a corridor driven down its middle: both walls echo with the same delay and "
                        "JADE often reports one; such walls have \"source\": \"side_wall\" in the GeoJSON; "
                        "docs/mapping.md, \"Side walls\")")
    p.add_argument("--no-partitions", action="store_true",
                   help="do not draw the partitions between the rooms behind a wall (hidden walls across the track, "
                        "\"source\": \"partition\" in the GeoJSON, found where the wall's echo vanishes beside them; "
                        "on the office floors' eight surveys hidden coverage 31-43 %% -> 41-81 %%, two false ones (2.8 %% of the true wall length on the one survey that has them); "
                        "docs/mapping.md, \"Partitions\")")
    p.add_argument("--no-hidden-continuation", action="store_true",
                   help="do not draw a hidden wall on past its echoes where the CSI of the poses beside it holds its "
                        "echo (\"source\": \"continued\" in the GeoJSON; on the office floors' eight surveys "
                        "hidden coverage median 58 -> 66 %%, no false wall; docs/mapping.md, \"Hidden walls drawn on\")")
    p.add_argument("--no-orientation-lean", action="store_true",
                   help="take the echoes' orientations as they are fitted in the pose adjustment; by default one "
                        "angle by which the walls on the left and on the right lean in mirror image (the "
                        "corridor's double bounces turn their CSI fits so, 0.4-2.2 deg on the office floors) is "
                        "estimated with the poses instead of being taken for heading (stats: "
                        "orientation_lean_deg; docs/mapping.md, \"The echoes' lean\")")
    p.add_argument("--no-square-plan", action="store_true",
                   help="leave each wall where and as its own poses fitted it; by default, last, walls within 5 deg "
                        "of the map's main direction (its line-of-sight walls' own) or of square to it are turned "
                        "onto it, and the pieces of one wall within 0.3 m of each other's line are put on one line "
                        "(not across a line-of-sight wall between them, nor plasterboard with brick or concrete; "
                        "on the office floors line of sight 6.1 -> 5.3 cm, hidden 8.4 -> 6.8 cm median; stats: "
                        "walls_squared, walls_on_shared_lines; docs/mapping.md, \"The plan squared\"). Use it "
                        "for a building whose walls meet a few degrees off square")
    p.add_argument("--no-material-labels", action="store_true",
                   help="do not label the walls' materials; by default, with the CSI fits and a survey without "
                        "thrumapper:wall_model, each wall seen from 3 poses or more is labelled plasterboard, brick "
                        "or concrete by how strong its echoes are against the line-of-sight walls' (GeoJSON "
                        "property \"material\"; docs/mapping.md, \"Materials\")")
    p.add_argument("--poses", metavar="FIRST:END",
                   help="map only the pose groups FIRST to END-1 (numbered from 0 as the survey holds them; "
                        "either may be left out, as in 100: for the rest). The fusion maps one pass along a "
                        "corridor: a survey driven down and back is mapped one pass at a time, e.g. --poses :100 "
                        "and --poses 100:")
    p.add_argument("--passes", action="store_true",
                   help="a survey that turns (down the corridor and back): map each pass along the corridor on "
                        "its own and merge them into one map, each later pass moved onto the previous pass's "
                        "corrected end and one wall's pieces put on one line; the poses of the turn itself "
                        "(passes of fewer than --min-wall-poses) are left out")
    p.add_argument("--paths", type=int, default=8, metavar="K", help="most echoes JADE reports per pose (default 8)")
    p.add_argument("--stages", type=int, default=1, metavar="N",
                   help="successive-cancellation stages of JADE (default 1: on the example scenes more stages "
                        "found more echoes but more spurious ones too, docs/mapping.md)")
    p.add_argument("--max-delay-s", type=float, default=60e-9, metavar="S", help="JADE's delay grid end (default 60e-9)")
    p.add_argument("--angles", type=int, default=360, help="JADE's angle grid size (default 360)")
    p.add_argument("--delays", type=int, default=240, help="JADE's delay grid size (default 240)")
    p.add_argument("--no-pose-correction", action="store_true", help="keep the odometry's poses")
    p.add_argument("--no-csi-refinement", action="store_true",
                   help="keep the walls fused from JADE's paths (default: refine each wall on the CSI with the "
                        "slab echo model, docs/mapping.md)")
    p.add_argument("--detections", choices=("fused", "measured"), default="fused",
                   help="detections written as the fused reflection points on the walls (default) or as "
                        "the measured echoes (the other set is written too, as kind \"echoes\")")
    p.add_argument("--max-range-m", type=float, default=8.0, metavar="M", help="ignore echoes farther (default 8 m)")
    p.add_argument("--min-wall-poses", type=int, default=5, metavar="N",
                   help="poses that must see a wall before it is mapped (default 5; fewer when the survey has fewer)")
    p.add_argument("--stats", metavar="STATS.json", help="write the counts and timings as JSON")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    return p


def jade_settings(paths=8, stages=1, max_delay_s=60e-9, angles=360, delays=240):
    """JadeSettings for mapping; `stages` is set when the estimator has successive cancellation."""
    from .jade_pipeline import JadeSettings

    settings = JadeSettings(num_angles=angles, num_delays=delays, delay_max_s=max_delay_s, max_paths=paths)
    if "stages" in getattr(JadeSettings, "__dataclass_fields__", {}):
        settings.stages = stages
    elif stages != 1:
        raise ValueError("--stages: this JADE has no successive cancellation (JadeSettings has no 'stages')")
    return settings


def pose_slice(text):
    """--poses FIRST:END as a slice of the pose groups (None for all). Raises ValueError."""
    if text is None:
        return None
    first, sep, end = text.partition(":")
    try:
        if not sep:
            raise ValueError
        bounds = [int(v) if v.strip() else None for v in (first, end)]
    except ValueError:
        raise ValueError(f"--poses {text}: expected FIRST:END, pose group numbers from 0 (e.g. 0:100 or 100:)") \
            from None
    if any(b is not None and b < 0 for b in bounds):
        raise ValueError(f"--poses {text}: pose group numbers start at 0")
    return slice(*bounds)


def map_survey(survey, fusion_settings=None, settings=None, system_delay_s=None, progress=None, timings=None,
               refine_on_csi=True, keep_results=False, build=True, pose_groups=None):
    """The whole chain on a read survey: RX calibration, JADE, wall fusion. Returns
    (FusedMap, info dict; info["fusion"] is the WallFusion, its CSI refiner holding the last
    map, for scripts that go on from it; with keep_results, info["jade_results"] the
    arguments WallFusion.add was given for each pose group, in order, for scripts that map
    part of the survey again). The wall model comes from the survey when it has one,
    overriding fusion_settings.material. build=False stops before the map is built (FusedMap
    None): for scripts that map the JADE results themselves. pose_groups: a slice of the
    survey's pose groups to map (one pass of a survey driven down and back), default all."""
    from . import jade_pipeline, rx_calibration
    from .wall_fusion import FusionSettings, RadarGeometry, WallFusion

    timings = {} if timings is None else timings
    info = {}
    started = time.perf_counter()
    calibration = rx_calibration.calibrate_survey(survey)
    timings["calibration_s"] = time.perf_counter() - started
    if calibration is not None:
        info["rx_calibration"] = calibration.summary()
    work = rx_calibration.calibrated_survey(survey, calibration)
    fusion_settings = fusion_settings or FusionSettings()
    if survey.wall_model is not None:
        fusion_settings.material = dict(survey.wall_model)
        fusion_settings.estimate_materials = False  # the survey states it
        info["wall_model"] = "survey thrumapper:wall_model"
    fusion = WallFusion(RadarGeometry.from_survey(survey), fusion_settings)
    settings = settings or jade_settings()
    started = time.perf_counter()
    if system_delay_s is None and survey.system_delay_s is None:
        system_delay_s = jade_pipeline.estimate_system_delay(work, jade_pipeline.group_frames_by_pose(work))
        info["system_delay"] = "measured on the direct path"
    info["system_delay_s"] = system_delay_s if system_delay_s is not None else survey.system_delay_s
    timings["system_delay_s"] = time.perf_counter() - started
    started = time.perf_counter()
    groups = 0
    if refine_on_csi:
        fusion.enable_csi_refinement(info["system_delay_s"])
    kept = info["jade_results"] = [] if keep_results else None
    for result in jade_pipeline.run_survey(work, settings, system_delay_s, progress, keep_csi=refine_on_csi,
                                           pose_groups=pose_groups):
        added = (result["pose"], result["paths"], result["frames"][0], result.get("csi"), result.get("tx_weights"))
        fusion.add(*added)
        if kept is not None:
            kept.append(added)
        groups += 1
    timings["jade_s"] = time.perf_counter() - started
    if groups == 0:
        raise ValueError("survey: no survey frames (only rx_reference frames, or none)")
    if not build:
        info["fusion"] = fusion
        return None, info
    started = time.perf_counter()
    fused = fusion.build_map()
    timings["fusion_s"] = time.perf_counter() - started
    fused.stats["timings"] = dict(timings)
    fused.stats.update({k: v for k, v in info.items() if isinstance(v, (str, int, float))})
    info["fusion"] = fusion
    return fused, info


def main(argv=None):
    args = build_parser().parse_args(argv)
    from . import ros_map
    from .survey import SurveyFormatError, read_survey
    from .wall_fusion import FusionSettings, _jsonable, plot_map

    def fail(message):
        print(f"thrumapper-map: {message}", file=sys.stderr)
        return 2

    if args.system_delay_s is not None and not (math.isfinite(args.system_delay_s) and args.system_delay_s >= 0):
        return fail(f"--system-delay-s: expected a delay >= 0, got {args.system_delay_s}")
    if not (args.ros_resolution > 0):
        return fail(f"--ros-resolution: expected > 0, got {args.ros_resolution}")
    try:
        survey = read_survey(args.survey)
    except (SurveyFormatError, OSError) as err:
        return fail(str(err))
    try:
        pose_groups = pose_slice(args.poses)
    except ValueError as err:
        return fail(str(err))
    import numpy as np

    from .survey import group_frames_by_pose
    from .wall_fusion import WallFusion, first_turn, merge_passes, survey_passes, track_turn_deg

    all_poses = np.array([pose for _, pose in group_frames_by_pose(survey)], float).reshape(-1, 3)
    numbers = np.arange(len(all_poses))[pose_groups if pose_groups is not None else slice(None)]
    if numbers.size == 0 and len(all_poses):
        return fail(f"--poses {args.poses}: picks none of the survey's {len(all_poses)} pose groups")
    turn = first_turn(all_poses[numbers], WallFusion.TRACK_MAX_TURN_DEG) if numbers.size else None
    passes = [(int(numbers[0]), int(numbers[-1]) + 1)] if numbers.size else []
    in_turns = 0
    if turn is not None and args.passes:
        found, in_turns = survey_passes(all_poses[numbers], WallFusion.TRACK_MAX_TURN_DEG, args.min_wall_poses)
        passes = [(int(numbers[a]), int(numbers[b - 1]) + 1) for a, b in found]
        if not passes:
            return fail(f"--passes: no pass of at least {args.min_wall_poses} poses (--min-wall-poses) along the track")
    elif turn is not None:
        at = int(numbers[turn])
        first, last = int(numbers[0]), int(numbers[-1])
        return fail(f"the track turns at pose group {at} of {first}-{last} (x {all_poses[at, 0]:.2f} m, "
                    f"y {all_poses[at, 1]:.2f} m: {track_turn_deg(all_poses[first], all_poses[at]):.0f} deg from "
                    f"the heading of group {first}); the fusion maps one pass along a corridor: map the passes "
                    f"one at a time, --poses {first}:{at} and --poses {at}:, or give --passes to map each and "
                    "merge them")
    material = args.material if args.material is not None else "plasterboard"
    if material == "none":
        material = None
    try:
        fusion_settings = FusionSettings(material=material, correct_poses=not args.no_pose_correction,
                                         max_range_m=args.max_range_m, min_wall_poses=args.min_wall_poses,
                                         estimate_materials=not args.no_material_labels,
                                         side_walls=not args.no_side_walls, partitions=not args.no_partitions,
                                         continue_hidden_walls=not args.no_hidden_continuation,
                                         orientation_lean=not args.no_orientation_lean,
                                         square_plan=not args.no_square_plan,
                                         correct_materials=not args.no_material_corrections)
        fusion_settings.check()
        settings = jade_settings(args.paths, args.stages, args.max_delay_s, args.angles, args.delays)
    except ValueError as err:
        return fail(str(err))
    progress = None
    if not args.quiet:
        from tqdm import tqdm

        def progress(groups):
            return tqdm(groups, desc="JADE", unit="pose", file=sys.stderr)
    total = time.perf_counter()
    try:
        if not args.quiet:
            print("thrumapper-map: calibrating, estimating, fusing ...", file=sys.stderr)
        if len(passes) > 1:
            maps = []
            for n, (first, end) in enumerate(passes):
                if not args.quiet:
                    print(f"thrumapper-map: pass {n + 1} of {len(passes)}: pose groups {first}-{end - 1}", file=sys.stderr)
                fused, info = map_survey(survey, dataclasses.replace(fusion_settings), settings, args.system_delay_s,
                                         progress, refine_on_csi=not args.no_csi_refinement,
                                         pose_groups=slice(first, end))
                maps.append(fused)
            fused = merge_passes(maps, info["fusion"])
            fused.stats["poses_in_turns"] = in_turns
        else:
            fused, info = map_survey(survey, fusion_settings, settings, args.system_delay_s, progress,
                                     refine_on_csi=not args.no_csi_refinement, pose_groups=pose_groups)
    except ValueError as err:
        return fail(str(err))
    fused.write_geojson(args.geojson, fused_detections=args.detections == "fused")
    written = [args.geojson]
    if args.png:
        plot_map(fused, args.png, truth=args.truth)
        written.append(args.png)
    if args.ros_map:
        written.extend(ros_map.write_ros_map(fused, args.ros_map, args.ros_resolution))
    elapsed = time.perf_counter() - total
    fused.stats["timings"]["total_s"] = elapsed
    if args.stats:
        with open(args.stats, "w", encoding="utf-8") as handle:
            json.dump(_jsonable(fused.stats), handle, indent=1)
        written.append(args.stats)
    st = fused.stats
    print(f"thrumapper-map: {st['poses']} poses, {st['echoes']} echoes -> {st['walls']} walls, "
          f"{st['corners']} corners, {st.get('openings', 0)} open doorways ({st['ghosts']} ghost echoes, {st['skipped_early']} early, "
          f"{st['skipped_nonfinite']} non-finite skipped) in {elapsed:.1f} s "
          f"({elapsed / max(st['poses'], 1):.3f} s/pose)", file=sys.stderr)
    if st.get("direct_leak_modelled"):
        # worth knowing on the radio's side: the TX chains' errors fill the null toward the RX
        print(f"thrumapper-map: the TX chains leave the direct path at {st['direct_leak_db']:.1f} dB of the data "
              f"after the nominal one is cancelled; modelled in the CSI fits (calibrating the TX chains removes it)",
              file=sys.stderr)
    for path in written:
        print(path)
    return 0


if __name__ == "__main__":
    sys.exit(main())
