#
# SPDX-License-Identifier: GPL-3.0-or-later
#
"""thrumapper-jade: joint angle-delay estimation on every pose of a CSI survey."""

import argparse
import json
import sys

from . import rx_calibration
from .jade_pipeline import JadeSettings, plot_surface, run_survey
from .survey import SurveyFormatError, read_survey

EPILOG = """\
output:
  one JSON object per line for each group of frames that share a pose (rx_reference frames,
  which calibrate the RX chains first, and a TX calibration's single-element frames are left
  out), strongest path first:
    {"frames": [0, 1, 2, 3], "pose": [x, y, heading],
     "paths": [{"aoa_deg": 243.4, "delay_s": 5.22e-09, "power": 0.0013}, ...]}
  aoa_deg: angle of arrival at the RX array centre, degrees in [0, 360), counter-clockwise
  from the robot's +x axis (its direction of travel). delay_s: propagation delay from the TX
  array centre to the RX array centre, the system delay removed (FORMATS.md). power: |gain|^2
  of the path in CSI units, averaged over the group's frames.

direct path:
  the direct TX->RX path is near-field: JADE's far-field model would see it as a spray of
  weak paths below ~3 ns. It is cancelled first, by projection onto the complement of its
  exact response (the frame's TX weights, the system delay); --keep-direct-path keeps it.

system delay:
  taken from --system-delay-s, else from the survey's thrumapper:system_delay_s, else
  measured on the direct TX->RX path, whose geometry is known (delays are then defined
  modulo 1/subcarrier spacing, about 1.07 us at 120 MHz / 128): on the frames sounded with
  one TX element alone when the survey has them (a TX calibration), else on the survey's
  frames, which a TX null steered at the receiver leaves too weak for it.

examples:
  thrumapper-sim examples/scenes/paper_4_2_wall_0p7m.yaml --out out/
  thrumapper-jade out/paper_4_2_wall_0p7m.sigmf-meta --paths 3 --png out/surface.png
  thrumapper-jade survey.sigmf-meta --max-delay-s 80e-9 | jq '.paths[0].delay_s'
  thrumapper-jade out/paper_4_3_hidden_2p2m.sigmf-meta --paths 3 --stages 3
"""


def build_parser():
    p = argparse.ArgumentParser(
        prog="thrumapper-jade",
        description="Find the echoes (angle of arrival and delay) in every pose of a CSI "
                    "survey (SigMF, thrumapper:kind \"csi\") with JADE, the joint "
                    "angle-delay MUSIC estimator, and print them as JSON lines.",
        epilog=EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("survey", help="the survey: NAME.sigmf-meta (or NAME, or NAME.sigmf-data)")
    p.add_argument("--paths", type=int, default=4, metavar="K",
                   help="most paths reported per pose (default 4); fewer when the eigenvalues "
                        "show fewer")
    p.add_argument("--png", metavar="SURFACE.png",
                   help="write the angle x delay surface of one pose group as a PNG")
    p.add_argument("--png-group", type=int, default=0, metavar="I",
                   help="which pose group the PNG shows (default 0, the first)")
    p.add_argument("--system-delay-s", type=float, metavar="S",
                   help="the system delay to remove, overriding the survey's")
    p.add_argument("--max-delay-s", type=float, default=60e-9, metavar="S",
                   help="delay grid end (default 60e-9: walls up to about 9 m)")
    p.add_argument("--angles", type=int, default=360, help="angle grid size over 360 deg (default 360)")
    p.add_argument("--delays", type=int, default=240, help="delay grid size (default 240)")
    p.add_argument("--stages", type=int, default=1, metavar="S",
                   help="successive cancellation: estimate, cancel the returns found, estimate "
                        "again on what is left, up to S stages (default 1); each path then "
                        "carries the \"stage\" that found it")
    p.add_argument("--keep-direct-path", action="store_true",
                   help="do not cancel the direct TX->RX path (by default it is projected out "
                        "with its exact near-field response before JADE)")
    p.add_argument("--smoothing-window", type=int, default=0, metavar="L",
                   help="subcarriers per smoothing window (default 0: N/3)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    return p


def main(argv=None):
    args = build_parser().parse_args(argv)
    try:
        survey = read_survey(args.survey)
        # the RX chains calibrated on the survey's reference frames, as thrumapper-map does
        survey = rx_calibration.calibrated_survey(survey, rx_calibration.calibrate_survey(survey))
    except (SurveyFormatError, OSError, ValueError) as e:
        print(f"thrumapper-jade: {e}", file=sys.stderr)
        return 2
    settings = JadeSettings(num_angles=args.angles, num_delays=args.delays,
                            delay_max_s=args.max_delay_s, max_paths=args.paths,
                            smoothing_window=args.smoothing_window, stages=args.stages,
                            cancel_direct_path=not args.keep_direct_path)
    progress = None
    if not args.quiet and sys.stderr.isatty():
        from tqdm import tqdm

        def progress(groups):
            return tqdm(groups, desc="poses", unit="pose", file=sys.stderr)
    png_written = False
    try:
        for i, result in enumerate(run_survey(survey, settings, args.system_delay_s, progress)):
            line = {k: result[k] for k in ("frames", "pose", "paths")}
            if args.stages == 1:  # the stage says nothing without successive cancellation
                line["paths"] = [{k: p[k] for k in ("aoa_deg", "delay_s", "power")}
                                 for p in line["paths"]]
            print(json.dumps(line), flush=True)
            if args.png and i == args.png_group:
                plot_surface(result, args.png)
                png_written = True
    except ValueError as e:
        print(f"thrumapper-jade: {e}", file=sys.stderr)
        return 2
    if args.png and not png_written:
        print(f"thrumapper-jade: --png-group {args.png_group}: the survey has fewer pose groups",
              file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
