#!/usr/bin/env python3
#
# SPDX-License-Identifier: GPL-3.0-or-later
#
"""The example flowgraphs: every examples/*.grc compiles with grcc against the source tree's
block descriptions, and the no-GUI simulated survey maps the §4.4 corridor end to end."""

import glob
import os
import py_compile
import subprocess
import sys
import tempfile
import unittest

from gnuradio import gr, gr_unittest

ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), "..", ".."))
GRC_DIR = os.path.join(ROOT, "grc")
EXAMPLES = sorted(glob.glob(os.path.join(ROOT, "examples", "*.grc")))


def grc_environment():
    """grcc's environment: the source tree's grc/ first, then GNU Radio's global block paths
    without any directory that holds (possibly stale, installed) thrumapper blocks, which
    GRC would otherwise load after ours and let override them."""
    env = dict(os.environ)
    env["GRC_BLOCKS_PATH"] = GRC_DIR
    global_paths = gr.prefs().get_string("grc", "global_blocks_path", "/usr/share/gnuradio/grc/blocks")
    keep = [p for p in global_paths.split(os.pathsep)
            if p and not glob.glob(os.path.join(p, "thrumapper_*.block.yml"))]
    env["GR_CONF_GRC_GLOBAL_BLOCKS_PATH"] = os.pathsep.join(keep or ["/usr/share/gnuradio/grc/blocks"])
    return env


def compile_flowgraphs(paths, out_dir):
    """grcc every flowgraph in paths into out_dir; (returncode, output)."""
    result = subprocess.run(["grcc", "-o", out_dir] + list(paths), env=grc_environment(),
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, timeout=120)
    return result.returncode, result.stdout


class qa_flowgraphs(gr_unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        cls.tmp = tempfile.TemporaryDirectory(prefix="thrumapper_fg_")
        cls.out = cls.tmp.name
        cls.rc, cls.log = compile_flowgraphs(EXAMPLES, cls.out)

    @classmethod
    def tearDownClass(cls):
        cls.tmp.cleanup()

    def test_every_example_compiles(self):
        names = {os.path.splitext(os.path.basename(p))[0] for p in EXAMPLES}
        # the flowgraphs issue 7 asks for are all there
        for wanted in ("simulated_survey", "simulated_survey_nogui", "usrp_survey", "calibration", "jade_inspector"):
            self.assertIn(wanted, names)
        self.assertEqual(self.rc, 0, self.log)
        self.assertNotIn("Traceback", self.log, self.log)
        self.assertNotIn("Failed to evaluate", self.log, self.log)
        for name in sorted(names):
            generated = os.path.join(self.out, name + ".py")
            self.assertTrue(os.path.exists(generated), f"{name}.grc did not generate {generated}:\n{self.log}")
            py_compile.compile(generated, doraise=True)

    def test_usrp_survey_is_timed_and_synchronised(self):
        """What the day with the radios needs is in the generated code (it cannot run here)."""
        with open(os.path.join(self.out, "usrp_survey.py"), encoding="utf-8") as handle:
            code = handle.read()
        for mb in range(4):
            for dev in ("usrp_tx", "usrp_rx"):
                self.assertIn(f"self.{dev}.set_clock_source('external', {mb})", code)
                self.assertIn(f"self.{dev}.set_time_source('external', {mb})", code)
        self.assertIn("self.usrp_rx.set_time_unknown_pps(uhd.time_spec(0))", code)
        self.assertIn("self.usrp_rx.set_start_time(uhd.time_spec(start_time_s))", code)
        self.assertIn("self.usrp_tx.set_time_next_pps(", code)  # the TX array joins the RX time base
        self.assertIn("zeromq.sub_msg_source(pose_address", code)
        self.assertIn("thrumapper.ofdm_sounder(sounding, sent_weights, start_time_s)", code)
        # the sounder sends the weights the TX calibration corrected; the survey records the design's
        self.assertIn("load_correction(tx_calibration, 8)", code)
        self.assertNotIn("self.msg_connect((self.weights, 'weights'), (self.sounder, 'weights'))", code)
        self.assertIn("thrumapper.survey_sink(", code)
        # 8 channels each way, over 4 motherboards
        self.assertEqual(code.count("channels=list(range(0,8))"), 2)

    def test_nogui_survey_maps_the_corridor(self):
        """simulated_survey_nogui on the paper's §4.4 corridor (29 poses x 4 frames, seeded):
        the map it writes is scored against the scene's truth.

        jade_estimator attaches each frame's CSI to its paths message and wall_fusion fits the
        echoes on it, as thrumapper-map does. Measured: line of sight 0.021 m RMS, coverage
        88 %; hidden 0.004 m (its pieces put on one line: 0.033 m before), coverage 34 %; no
        false wall; trajectory 0.026 m (without the CSI: 0.100 / 0.210 m, trajectory 0.025 m;
        thrumapper-map on the same scene, scripts/demo.sh: 0.030 / 0.029 m). The bounds are the issue's targets for the walls (5 cm
        and 12 cm) and fail on a broken chain: the CSI lost on the way (the slab correction's
        10 cm), a wall placed from the wrong delay cell, a lost direct-path cancellation (the
        spray below 3 ns becomes walls) or poses not reaching the fusion (an empty map)."""
        from gnuradio.thrumapper import cli_sim, evaluation

        work = os.path.join(self.out, "e2e")
        os.makedirs(work, exist_ok=True)
        scene = os.path.join(ROOT, "examples", "scenes", "paper_4_4_corridor_corner.yaml")
        self.assertEqual(cli_sim.main([scene, "--out", work, "--quiet"]), 0)
        survey = os.path.join(work, "paper_4_4_corridor_corner.sigmf-meta")
        truth = os.path.join(work, "paper_4_4_corridor_corner.truth.geojson")
        geojson, png = os.path.join(work, "map.geojson"), os.path.join(work, "map.png")
        run = subprocess.run([sys.executable, os.path.join(self.out, "simulated_survey_nogui.py"),
                              "--survey", survey, "--geojson", geojson, "--png", png, "--system-delay-s", "20e-9"],
                             cwd=work, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, timeout=240)
        self.assertEqual(run.returncode, 0, run.stdout)
        self.assertNotIn("Traceback", run.stdout, run.stdout)
        self.assertTrue(os.path.getsize(png) > 10000, "no map picture")
        with open(png, "rb") as handle:
            self.assertEqual(handle.read(8), b"\x89PNG\r\n\x1a\n")
        scores = evaluation.score_map(geojson, truth)
        los, hidden = scores["classes"]["line_of_sight"], scores["classes"]["hidden"]
        print(f"simulated_survey_nogui on the corridor: LoS {los['detections']['rms_m']:.3f} m RMS, "
              f"coverage {los['coverage']:.2f}; hidden {hidden['detections']['rms_m']}, coverage "
              f"{hidden['coverage']:.2f}; false wall {scores['false_wall_length_m']:.2f} m; trajectory "
              f"{scores['trajectory']['rms_m']:.3f} m")
        self.assertGreaterEqual(los["detections"]["count"], 30)
        self.assertLess(los["detections"]["rms_m"], 0.05)
        self.assertGreater(los["coverage"], 0.8)
        self.assertIsNotNone(hidden["detections"]["rms_m"], "no hidden wall found")
        self.assertLess(hidden["detections"]["rms_m"], 0.12)
        self.assertGreater(hidden["coverage"], 0.2)
        self.assertLess(scores["false_wall_length_m"], 0.5)
        self.assertEqual(scores["trajectory"]["count"], 29)
        self.assertLess(scores["trajectory"]["rms_m"], 0.08)


if __name__ == "__main__":
    gr_unittest.run(qa_flowgraphs)
