#
# SPDX-License-Identifier: GPL-3.0-or-later
#
"""thrumapper-eval: score a map (GeoJSON) against the ground truth (GeoJSON)."""

import argparse
import json
import sys

EPILOG = """\
what it measures, per class (line_of_sight, hidden):
  detection error   distance from each point of the map's "detections" MultiPoints to the
                    nearest true wall face of the same class: RMS and median
  coverage          true wall length within --coverage-tolerance (0.3 m) of a map wall
  false wall        map wall length farther than --false-tolerance (0.5 m) from every true wall
and overall: true corners with a map corner within --corner-tolerance (0.5 m), open doorways
(features "kind": "opening", which thrumapper-map and thrumapper-sim's truth write) found within
--opening-tolerance (0.5 m) of a true one's middle and the RMS error of their jambs, and the
trajectory error (pointwise RMS between the map's and the true trajectory). Below the table,
the true walls least covered (--missed, 5): name, class, length uncovered and where, so a low
coverage says which walls the map misses (the JSON holds them all, "missed_walls"); and where
each class's detection error comes from (--sources, 3): the detections more than
--coverage-tolerance from every true wall of their class, grouped into those lying on a true
wall of the other class (a wall mapped in the wrong class) and those near no true wall (a
misplaced or ghost wall), by true wall, with the share of the squared error they carry. An RMS
of 0.6 m with "97 %  10 detections ... on a true wall of the other class: exterior_north" is a
classing problem on one wall, not a map 0.6 m off.

Both files are FORMATS.md maps: a FeatureCollection with "thrumapper:crs": "local-metres".
thrumapper-sim writes the truth (NAME.truth.geojson); the mapper writes the map.

examples:
  thrumapper-eval office.map.geojson office_floor.truth.geojson
  thrumapper-eval map.geojson truth.geojson --json > scores.json
  thrumapper-eval map.geojson truth.geojson --coverage-tolerance 0.2
  thrumapper-eval map.geojson truth.geojson --missed 20     # list more of the walls missed
  thrumapper-eval map.geojson truth.geojson --sources 10    # and more of the error sources
  thrumapper-eval map.geojson truth.geojson --align         # the map's shape, its frame's turn taken out

exit status: 0 scored, 2 a file is missing or breaks the format (the message names the field).
"""


def _parser():
    parser = argparse.ArgumentParser(
        prog="thrumapper-eval",
        description="Score a thrumapper map against the ground truth: wall detection error,\n"
                    "coverage and false walls per class, corners and open doorways found, trajectory error.",
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("map", metavar="MAP.geojson", help="the map to score")
    parser.add_argument("truth", metavar="TRUTH.geojson", help="the ground truth (thrumapper-sim writes one)")
    parser.add_argument("--json", action="store_true", help="print the scores as JSON instead of a table")
    parser.add_argument("--coverage-tolerance", type=float, default=0.3, metavar="M",
                        help="a true wall counts as covered within this distance of a map wall (default 0.3 m)")
    parser.add_argument("--false-tolerance", type=float, default=0.5, metavar="M",
                        help="a map wall counts as false beyond this distance from every true wall (default 0.5 m)")
    parser.add_argument("--corner-tolerance", type=float, default=0.5, metavar="M",
                        help="a true corner counts as found within this distance of a map corner (default 0.5 m)")
    parser.add_argument("--opening-tolerance", type=float, default=0.5, metavar="M",
                        help="a true open doorway counts as found when a map opening's middle is within this "
                             "distance of its middle (default 0.5 m)")
    parser.add_argument("--align", action="store_true",
                        help="first move the map by the rigid move (turn and shift) that puts its trajectory "
                             "closest to the true one, pose by pose, and score what is left: the map's shape "
                             "without its frame's error (a map is drawn in its first pose's frame; a small turn "
                             "of that frame moves walls 20 m away by centimetres). The table's first lines say "
                             "the move; the JSON has it as \"aligned\". Both trajectories must have the "
                             "same number of poses")
    parser.add_argument("--missed", type=int, default=5, metavar="N",
                        help="list the N true walls with the most length uncovered below the table "
                             "(default 5; 0 lists none)")
    parser.add_argument("--sources", type=int, default=3, metavar="N",
                        help="list each class's N largest sources of detection error below the table "
                             "(default 3; 0 lists none)")
    return parser


def main(argv=None) -> int:
    args = _parser().parse_args(argv)
    from . import evaluation

    for name in ("coverage_tolerance", "false_tolerance", "corner_tolerance", "opening_tolerance"):
        if not getattr(args, name) > 0:
            print(f"thrumapper-eval: error: --{name.replace('_', '-')} must be > 0", file=sys.stderr)
            return 2
    for name in ("missed", "sources"):
        if getattr(args, name) < 0:
            print(f"thrumapper-eval: error: --{name} must be >= 0", file=sys.stderr)
            return 2
    aligned = None
    try:
        map_data = evaluation.load_map(args.map)
        truth_data = evaluation.load_map(args.truth)
        if args.align:
            map_data, aligned = evaluation.align_to_truth(map_data, truth_data)
    except evaluation.MapFormatError as err:
        print(f"thrumapper-eval: error: {err}", file=sys.stderr)
        return 2
    scores = evaluation.score_map(map_data, truth_data, coverage_tolerance_m=args.coverage_tolerance,
                                  false_tolerance_m=args.false_tolerance, corner_tolerance_m=args.corner_tolerance,
                                  opening_tolerance_m=args.opening_tolerance)
    if aligned is not None:
        scores["aligned"] = aligned
    if args.json:
        print(json.dumps(scores, indent=2))
    else:
        print(evaluation.format_table(scores, missed=args.missed, sources=args.sources))
    return 0


if __name__ == "__main__":
    sys.exit(main())
