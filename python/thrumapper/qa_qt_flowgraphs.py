#!/usr/bin/env python3
#
# SPDX-License-Identifier: GPL-3.0-or-later
#
"""The QT GUI flowgraphs start headless (QT_QPA_PLATFORM=offscreen), run a few seconds and
stop cleanly on SIGTERM (their generated handler stops the top block and quits Qt).
scripts/screenshot.sh takes the picture of jade_inspector under Xvfb."""

import os
import signal
import subprocess
import sys
import tempfile
import time
import unittest

from gnuradio import gr_unittest

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from qa_flowgraphs import ROOT, compile_flowgraphs  # noqa: E402


class qa_qt_flowgraphs(gr_unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        cls.tmp = tempfile.TemporaryDirectory(prefix="thrumapper_qt_")
        cls.out = cls.tmp.name
        cls.rc, cls.log = compile_flowgraphs(
            [os.path.join(ROOT, "examples", name + ".grc") for name in ("jade_inspector", "simulated_survey")], cls.out)

    @classmethod
    def tearDownClass(cls):
        cls.tmp.cleanup()

    def run_headless(self, script, args, seconds):
        """Run a generated QT flowgraph offscreen for `seconds`, then SIGTERM it: (returncode,
        output). Fails if it exits before, or does not stop within 20 s."""
        env = dict(os.environ)
        env["QT_QPA_PLATFORM"] = "offscreen"
        env["XDG_CONFIG_HOME"] = os.path.join(self.out, "config")  # QSettings of the window
        env["XDG_RUNTIME_DIR"] = self.out
        log_path = os.path.join(self.out, os.path.basename(script) + ".log")
        with open(log_path, "w") as log:
            proc = subprocess.Popen([sys.executable, os.path.join(self.out, script)] + args, cwd=ROOT, env=env,
                                    stdout=log, stderr=subprocess.STDOUT)
            deadline = time.monotonic() + seconds
            while time.monotonic() < deadline and proc.poll() is None:
                time.sleep(0.2)
            running = proc.poll() is None
            if running:
                proc.send_signal(signal.SIGTERM)
            try:
                proc.wait(timeout=20)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
                self.fail(f"{script} did not stop within 20 s of SIGTERM")
        with open(log_path) as log:
            output = log.read()
        self.assertTrue(running, f"{script} exited by itself within {seconds} s:\n{output}")
        return proc.returncode, output

    def test_jade_inspector_runs_and_stops(self):
        self.assertEqual(self.rc, 0, self.log)
        rc, output = self.run_headless("jade_inspector.py", [], 8)
        self.assertEqual(rc, 0, output)
        self.assertNotIn("Traceback", output, output)
        # the receive chain calibrated the RX channels from the reference frames: data flowed
        self.assertIn("calibrating (start)", output, output)

    def test_simulated_survey_gui_runs_and_stops(self):
        from gnuradio.thrumapper import cli_sim

        self.assertEqual(self.rc, 0, self.log)
        scene = os.path.join(ROOT, "examples", "scenes", "paper_4_3_hidden_1p5m.yaml")
        self.assertEqual(cli_sim.main([scene, "--out", self.out, "--quiet"]), 0)
        survey = os.path.join(self.out, "paper_4_3_hidden_1p5m.sigmf-meta")
        rc, output = self.run_headless("simulated_survey.py", ["--survey", survey], 6)
        self.assertEqual(rc, 0, output)
        self.assertNotIn("Traceback", output, output)


if __name__ == "__main__":
    gr_unittest.run(qa_qt_flowgraphs)
