#!/usr/bin/env python3
#
# SPDX-License-Identifier: GPL-3.0-or-later
#
"""thrumapper-jade from the command line: JSON lines, the PNG, and clear errors."""

import json
import math
import os
import subprocess
import sys
import tempfile

import numpy as np
from gnuradio import gr_unittest

from gnuradio import thrumapper
from gnuradio.thrumapper import building_sim, scene, survey

C = thrumapper.speed_of_light_m_s


def run_cli(*args):
    return subprocess.run([sys.executable, "-m", "gnuradio.thrumapper.cli_jade", *args],
                          capture_output=True, text=True, timeout=300)


class qa_cli_jade(gr_unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        cls.tmp = tempfile.TemporaryDirectory()
        # a metal wall 2.2 m to the right (§4.2), two poses 0.5 m apart, 3 frames each
        cls.scene = scene.load_scene({
            "name": "wall", "seed": 3,
            "radar": {"elements": 8, "radius_m": 0.08, "baseline_m": 0.7, "carrier_hz": 2.44e9,
                      "bandwidth_hz": 120e6, "subcarriers": 64},
            "walls": [{"segment": [[-6, -2.2], [6, -2.2]], "material": "metal"}],
            "trajectory": {"poses_deg": [[0, 0, 0], [0.5, 0, 0]]},
            "frames_per_pose": 3,
            "noise": {"power_db": -100},
            "impairments": {"system_delay_s": 35e-9, "system_delay_known": True},
        })
        res = building_sim.simulate_survey(cls.scene, progress=False)
        sc = cls.scene
        cls.meta = survey.write_survey(
            os.path.join(cls.tmp.name, "wall"), res.csi,
            subcarrier_offsets_hz=sc.radar.subcarrier_offsets_hz,
            center_frequency_hz=sc.radar.carrier_hz, rx_elements_m=sc.radar.rx_elements_m,
            tx_elements_m=sc.radar.tx_elements_m, tx_weights=res.tx_weights,
            poses=res.poses_odometry, frame_types=res.frame_types, system_delay_s=35e-9)

    @classmethod
    def tearDownClass(cls):
        cls.tmp.cleanup()

    def test_json_lines_per_pose(self):
        png = os.path.join(self.tmp.name, "surface.png")
        out = run_cli(self.meta, "--paths", "3", "--png", png, "--quiet")
        self.assertEqual(out.returncode, 0, out.stderr)
        lines = [json.loads(line) for line in out.stdout.splitlines()]
        self.assertEqual(len(lines), 2)
        self.assertEqual(lines[0]["frames"], [0, 1, 2])
        self.assertEqual(lines[1]["frames"], [3, 4, 5])
        self.assertEqual(sorted(lines[0]), ["frames", "paths", "pose"])
        self.assertEqual(len(lines[1]["pose"]), 3)
        # the wall's echo: reflection point midway between the arrays, 2.2 m away
        want_delay = 2 * math.hypot(2.2, 0.35) / C
        for line in lines:
            self.assertLessEqual(len(line["paths"]), 3)
            self.assertEqual(sorted(line["paths"][0]), ["aoa_deg", "delay_s", "power"])
            wall = min(line["paths"], key=lambda p: abs(p["delay_s"] - want_delay))
            self.assertLess(abs(wall["delay_s"] - want_delay), 0.1e-9)
            want_aoa = math.degrees(math.atan2(-2.2, -0.35)) % 360
            self.assertLess(abs(wall["aoa_deg"] - want_aoa), 1.5)
            for p in line["paths"]:
                self.assertTrue(0 <= p["aoa_deg"] < 360)
        self.assertTrue(os.path.getsize(png) > 10000)

    def test_override_system_delay(self):
        out = run_cli(self.meta, "--paths", "3", "--system-delay-s", "30e-9", "--quiet")
        self.assertEqual(out.returncode, 0, out.stderr)
        want_delay = 2 * math.hypot(2.2, 0.35) / C + 5e-9  # 5 ns less removed
        delays = [p["delay_s"] for p in json.loads(out.stdout.splitlines()[0])["paths"]]
        self.assertLess(min(abs(d - want_delay) for d in delays), 0.1e-9)

    def broken_copy(self, edit_meta=None, truncate_bytes=0):
        d = tempfile.mkdtemp(dir=self.tmp.name)
        base = os.path.join(d, "broken")
        with open(self.meta) as f:
            meta = json.load(f)
        if edit_meta:
            edit_meta(meta)
        with open(base + ".sigmf-meta", "w") as f:
            json.dump(meta, f)
        data = open(self.meta.replace(".sigmf-meta", ".sigmf-data"), "rb").read()
        with open(base + ".sigmf-data", "wb") as f:
            f.write(data[:len(data) - truncate_bytes])
        return base + ".sigmf-meta"

    def test_malformed_surveys_get_one_clear_error(self):
        cases = [
            (lambda m: m["global"].pop("thrumapper:rx_elements"), 0, "thrumapper:rx_elements"),
            (lambda m: m["global"].update({"core:datatype": "ci16_le"}), 0, "core:datatype"),
            (lambda m: m["global"].update({"thrumapper:kind": "radar"}), 0, "thrumapper:kind"),
            (None, 8 * 64 * 8 // 2, "sigmf-data"),
        ]
        for edit, cut, field in cases:
            out = run_cli(self.broken_copy(edit, cut), "--quiet")
            self.assertEqual(out.returncode, 2, out.stdout)
            self.assertIn(field, out.stderr)
            self.assertEqual(len(out.stderr.strip().splitlines()), 1, out.stderr)
            self.assertNotIn("Traceback", out.stderr)

    def test_missing_file(self):
        out = run_cli(os.path.join(self.tmp.name, "nothing.sigmf-meta"), "--quiet")
        self.assertEqual(out.returncode, 2)
        self.assertNotIn("Traceback", out.stderr)

    def test_help_teaches(self):
        out = run_cli("--help")
        self.assertEqual(out.returncode, 0)
        for word in ("aoa_deg", "delay_s", "system delay", "examples"):
            self.assertIn(word, out.stdout)


if __name__ == "__main__":
    gr_unittest.run(qa_cli_jade)
