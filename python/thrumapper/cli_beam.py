#
# SPDX-License-Identifier: GPL-3.0-or-later
#
"""thrumapper-beam: design TX null-steering weights and show the wideband beam pattern."""

import argparse
import json
import math
import sys

import numpy as np

from . import thrumapper_python as _core

EPILOG = """\
bearings: seen from the TX array centre, degrees counter-clockwise from the robot's +x axis
  (its direction of travel). In the default layout (TX array at x = -0.35 m, RX array at
  +0.35 m) the receiver is at 0 deg; a wall on the right-hand side is at 180-360 deg, and its
  specular point at atan(standoff / 0.35 m) below the baseline (297 deg at 0.7 m).

coupling: the direct TX->RX coupling over every RX element and subcarrier, relative to a beam
  of the same power aimed at the receiver. Per-chain phase errors set a floor under it; the
  expected coupling for 1, 2 and 5 deg rms is printed too.

examples:
  thrumapper-beam --main-lobe-deg 300 --png beam.png
  thrumapper-beam --main-lobe-deg 290 --null-deg 200 --null-deg 150 --json
  thrumapper-beam --main-lobe-deg 300 --eq9          # the paper's plane-wave eq. 9, for comparison
  thrumapper-beam --tx-calibration out/tx_calibration.sigmf-meta --save out/tx_calibration.json

TX calibration (--tx-calibration SURVEY): the survey's frames sounded with one TX element alone
  (calibration.grc records them on the radios, docs/hardware.md; thrumapper-sim writes them
  with --tx-calibration-frames F or a scene's impairments.tx_calibration_frames) measure each TX chain's gain, phase and delay on the
  direct path, the walls' echoes fitted and removed first. It prints them, the coupling the
  chains leave in the null uncorrected, and the weights to send (each design weight times
  1/alpha_k). --save writes them as JSON for usrp_survey.grc's "TX calibration" parameter.
  The survey's own geometry and RX reference frames are used; its array must match --elements.
"""


def build_parser():
    p = argparse.ArgumentParser(
        prog="thrumapper-beam",
        description="Design the TX weights (main lobe at the walls, nulls at the receiver and "
                    "at corners), print them with the null depth, and plot the beam pattern "
                    "across the band.",
        epilog=EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--main-lobe-deg", type=float, default=300.0, help="main lobe bearing (default 300)")
    p.add_argument("--null-deg", type=float, action="append", default=[],
                   help="a far-field null, e.g. a corner's bearing (repeatable)")
    p.add_argument("--no-receiver-null", action="store_true", help="do not null the receiving array")
    p.add_argument("--eq9", action="store_true",
                   help="use the paper's eq. 9 (plane waves, one null at the receiver's bearing)")
    p.add_argument("--target-depth-db", type=float, default=-45.0,
                   help="receiver null depth to aim for (default -45)")
    p.add_argument("--elements", type=int, default=8, help="elements per UCA (default 8)")
    p.add_argument("--radius-m", type=float, default=0.08, help="UCA radius (default 0.08)")
    p.add_argument("--baseline-m", type=float, default=0.7, help="TX-RX array distance (default 0.7)")
    p.add_argument("--carrier-hz", type=float, default=2.44e9)
    p.add_argument("--bandwidth-hz", type=float, default=120e6)
    p.add_argument("--png", metavar="BEAM.png", help="write the beam pattern at the band's edges and centre")
    p.add_argument("--json", action="store_true", help="print a JSON object instead of text")
    p.add_argument("--tx-calibration", metavar="SURVEY",
                   help="measure the TX chains from this survey's single-element frames and print the "
                        "corrected weights (see below)")
    p.add_argument("--save", metavar="FILE.json", help="with --tx-calibration: write the calibration as JSON")
    return p


def _tx_calibration(path, num_tx):
    """(TxCalibration, survey) from the single-element frames of a survey; ValueError naming
    what is wrong."""
    from . import rx_calibration, survey, tx_calibration

    try:
        sv = survey.read_survey(path)
    except (survey.SurveyFormatError, OSError) as err:
        raise ValueError(f"--tx-calibration: {err}") from None
    if sv.num_tx != num_tx:
        raise ValueError(f"--tx-calibration: {path} has {sv.num_tx} TX elements, the design {num_tx} (--elements)")
    cal = tx_calibration.calibrate_survey_tx(sv, rx_calibration.calibrate_survey(sv))
    if cal is None:
        raise ValueError(f"--tx-calibration: {path} has no frame sounded with one TX element alone")
    return cal


def main(argv=None):
    args = build_parser().parse_args(argv)
    try:
        radar = _core.radar_description.make_uca_pair(args.elements, args.radius_m, args.baseline_m,
                                                      args.carrier_hz, args.bandwidth_hz, 128)
        ns = _core.null_steering(radar)
        ns.set_target_depth(args.target_depth_db)
        main_rad = math.radians(args.main_lobe_deg)
        if args.eq9:
            weights = ns.eq9_weights(main_rad, ns.receiver_bearing_rad)
        else:
            weights = ns.design(main_rad, [math.radians(d) for d in args.null_deg], not args.no_receiver_null)
        if args.save and not args.tx_calibration:
            raise ValueError("--save needs --tx-calibration")
        cal = _tx_calibration(args.tx_calibration, args.elements) if args.tx_calibration else None
    except ValueError as e:
        print(f"thrumapper-beam: {e}", file=sys.stderr)
        return 2
    report = {
        "weights": [[w.real, w.imag] for w in weights],
        "main_lobe_deg": args.main_lobe_deg,
        "null_deg": args.null_deg,
        "coupling_db": ns.coupling_db(weights),
        "expected_coupling_db": {f"{e:g}": ns.expected_coupling_db(weights, math.radians(e)) for e in (1, 2, 5)},
        "main_lobe_gain_db": float(ns.beam_pattern_db(weights, [main_rad], [args.carrier_hz])[0, 0]),
    }
    if cal is not None:
        from . import tx_calibration

        chains = 1.0 / cal.correction  # the measured α_k at the carrier
        sent = cal.corrected_weights(weights)
        report["tx_calibration"] = tx_calibration.calibration_json(cal)
        report["coupling_uncorrected_db"] = ns.coupling_db([complex(w) for w in np.asarray(weights) * chains])
        report["corrected_weights"] = [[w.real, w.imag] for w in sent]
        if args.save:
            try:
                with open(args.save, "w", encoding="utf-8") as handle:
                    json.dump(report["tx_calibration"], handle, indent=1)
                    handle.write("\n")
            except OSError as err:
                print(f"thrumapper-beam: --save {args.save}: {err.strerror}", file=sys.stderr)
                return 2
    if args.json:
        print(json.dumps(report))
    else:
        print(f"main lobe {args.main_lobe_deg:.1f} deg: gain {report['main_lobe_gain_db']:.2f} dB over one element "
              f"(plain beam {10 * math.log10(args.elements):.2f} dB)")
        print(f"direct coupling {report['coupling_db']:.1f} dB (vs a beam aimed at the receiver); with rms "
              "phase error per chain: " + ", ".join(f"{k} deg {v:.1f} dB" for k, v in report["expected_coupling_db"].items()))
        for k, w in enumerate(weights):
            print(f"  w[{k}] = {abs(w):.4f} at {math.degrees(math.atan2(w.imag, w.real)):8.2f} deg")
        if cal is not None:
            print(cal.summary())
            print(f"coupling with these chains uncorrected {report['coupling_uncorrected_db']:.1f} dB; send instead "
                  "(design weight / chain):")
            for k, (w, g, ph) in enumerate(zip(sent, cal.gain_db, cal.phase_rad)):
                print(f"  w[{k}] = {abs(w):.4f} at {math.degrees(math.atan2(w.imag, w.real)):8.2f} deg   "
                      f"(chain {g:+.2f} dB, {math.degrees(ph):+.2f} deg)")
            if args.save:
                print(f"saved {args.save}")
    if args.png:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
        angles = np.radians(np.arange(0, 360, 0.5))
        offsets = radar.subcarrier_offsets_hz
        freqs = [args.carrier_hz + offsets[0], args.carrier_hz, args.carrier_hz + offsets[-1]]
        g = ns.beam_pattern_db(weights, list(angles), freqs)
        fig, ax = plt.subplots(figsize=(8, 4.5), dpi=110)
        for row, f in zip(g, freqs):
            ax.plot(np.degrees(angles), row, label=f"{f / 1e9:.3f} GHz")
        ax.axvline(args.main_lobe_deg, color="k", ls="--", lw=0.8, label="main lobe")
        ax.axvline(math.degrees(ns.receiver_bearing_rad), color="r", ls=":", lw=1, label="receiver")
        for d in args.null_deg:
            ax.axvline(d, color="m", ls=":", lw=1)
        ax.set_ylim(-50, 12)
        ax.set_xlim(0, 360)
        ax.set_xlabel("bearing from the TX centre (deg, CCW from robot +x)")
        ax.set_ylabel("far-field gain (dB over one element)")
        ax.set_title(f"TX beam: coupling to the receiver {report['coupling_db']:.1f} dB")
        ax.grid(alpha=0.3)
        ax.legend(loc="lower left", fontsize=8)
        fig.tight_layout()
        fig.savefig(args.png)
        plt.close(fig)
    return 0


if __name__ == "__main__":
    sys.exit(main())
