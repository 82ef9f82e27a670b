#!/usr/bin/env python3
#
# SPDX-License-Identifier: GPL-3.0-or-later
#
"""thrumapper-map end to end on short simulated surveys: RX calibration, the system delay,
JADE, fusion, and the GeoJSON, PNG and ROS map it writes; and its errors."""

import contextlib
import io
import json
import math
import os
import tempfile

import numpy as np
from gnuradio import gr_unittest

from gnuradio.thrumapper import building_sim, cli_map, evaluation, ros_map, rx_calibration, scene, survey


def corridor_scene(tx_weights, impaired=True, known_delay=True, material="metal", walls=True, back=False):
    """A wall with its face 0.7 m to the right, a 1.6 m scan in 20 cm steps. Metal by default:
    its echo has one face, so JADE's delay is the geometry's and the map can be held to it."""
    data = {
        "name": "corridor", "seed": 21,
        "radar": {"elements": 8, "radius_m": 0.08, "baseline_m": 0.7, "carrier_hz": 2.44e9,
                  "bandwidth_hz": 120e6, "subcarriers": 64},
        "tx_weights": tx_weights,
        "walls": [{"segment": [[-4.0, -0.701], [6.0, -0.701]], "material": material}] if walls else [],
        "trajectory": {"waypoints": [[0.0, 0.0], [1.6, 0.0]], "step_m": 0.2},
        "frames_per_pose": 2,
        "noise": {"power_db": -110},
        "impairments": {"system_delay_s": 27e-9, "system_delay_known": known_delay},
    }
    if back:  # down the corridor and back: the robot turns round at x = 1.6 m
        data["trajectory"]["waypoints"] = [[0.0, 0.0], [1.6, 0.0], [1.6, 0.001], [0.0, 0.001]]
    if impaired:
        data["impairments"].update({"rx": {"gain_db_std": 0.5, "phase_deg": "uniform", "delay_ps_std": 20},
                                    "dc_offset_db": -75})
    return scene.load_scene(data)


def write(sc, directory, name):
    res = building_sim.simulate_survey(sc, progress=False)
    meta = survey.write_survey(
        os.path.join(directory, name), res.csi, subcarrier_offsets_hz=sc.radar.subcarrier_offsets_hz,
        center_frequency_hz=sc.radar.carrier_hz, rx_elements_m=sc.radar.rx_elements_m,
        tx_elements_m=sc.radar.tx_elements_m, tx_weights=res.tx_weights, poses=res.poses_odometry,
        frame_types=res.frame_types,
        system_delay_s=sc.impairments["system_delay_s"] if sc.impairments["system_delay_known"] else None,
        wall_model=res.wall_model)
    truth = os.path.join(directory, name + ".truth.geojson")
    with open(truth, "w") as handle:
        json.dump(building_sim.truth_geojson(sc), handle)
    return meta, truth, res


def run(argv):
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = cli_map.main(argv)
    return code, out.getvalue(), err.getvalue()


class qa_cli_map(gr_unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        cls.tmp = tempfile.TemporaryDirectory()
        cls.null = {"mode": "null_steer", "main_lobe_deg": 270}
        cls.meta, cls.truth, cls.res = write(corridor_scene(cls.null), cls.tmp.name, "corridor")

    @classmethod
    def tearDownClass(cls):
        cls.tmp.cleanup()

    def path(self, name):
        return os.path.join(self.tmp.name, name)

    def test_map_files(self):
        """The whole chain on a survey with impaired RX chains: the wall 0.7 m to the right is
        mapped where it is, and every output follows its format."""
        code, out, err = run([self.meta, "--geojson", self.path("map.geojson"), "--png", self.path("map.png"),
                              "--ros-map", self.path("ros"), "--stats", self.path("stats.json"), "--quiet",
                              "--material", "metal"])
        self.assertEqual(code, 0, err)
        self.assertIn("map.geojson", out)
        fused = evaluation.load_map(self.path("map.geojson"))  # FORMATS.md, or it raises
        self.assertTrue(fused.walls)
        self.assertIsNotNone(fused.trajectory)
        scores = evaluation.score_map(fused, self.truth)
        los = scores["classes"]["line_of_sight"]
        # the wall's face is at y = -0.7: mapped within 3 cm, covering the scan
        wall = min(fused.walls, key=lambda w: float(np.abs(w["coordinates"][:, 1] + 0.7).max()))
        self.assertLess(float(np.abs(wall["coordinates"][:, 1] + 0.7).max()), 0.03, wall)
        self.assertEqual(wall["class"], "line_of_sight")
        self.assertGreater(los["covered_length_m"], 1.4, json.dumps(los))
        self.assertLess(los["detections"]["median_m"], 0.03, json.dumps(los))
        with open(self.path("map.png"), "rb") as handle:
            self.assertEqual(handle.read(8), b"\x89PNG\r\n\x1a\n")
        grid = ros_map.read_pgm(self.path("ros.pgm"))
        with open(self.path("ros.yaml")) as handle:
            meta = dict(line.split(": ", 1) for line in handle.read().splitlines())
        self.assertEqual(meta["image"], "ros.pgm")
        resolution = float(meta["resolution"])
        origin = [float(v) for v in meta["origin"].strip("[]").split(",")]
        # the wall's pixels are occupied: row counted from the top, origin at the bottom left
        row = grid.shape[0] - 1 - int(math.floor((-0.7 - origin[1]) / resolution))
        col = int(math.floor((0.8 - origin[0]) / resolution))
        self.assertEqual(grid[row - 2:row + 3, col].min(), ros_map.OCCUPIED)
        # the corridor between the robot and the wall is free, beyond it unknown
        row_free = grid.shape[0] - 1 - int(math.floor((-0.35 - origin[1]) / resolution))
        self.assertIn(ros_map.FREE, grid[row_free, col - 1:col + 2])
        self.assertTrue(np.all(grid[0, :] == ros_map.UNKNOWN))  # nothing seen at the margin
        with open(self.path("stats.json")) as handle:
            stats = json.load(handle)
        self.assertEqual(stats["poses"], 9)
        self.assertIn("jade_s", stats["timings"])

    def test_orientation_lean_flag(self):
        """--no-orientation-lean leaves the echoes' lean out of the pose adjustment: the stats
        report it as exactly 0, where by default it is estimated (a value of its own, here
        near 0: one wall, no facing pair to lean)."""
        leans = {}
        for flag in ([], ["--no-orientation-lean"]):
            code, _, err = run([self.meta, "--geojson", self.path("lean.geojson"), "--stats", self.path("lean.json"),
                                "--quiet", "--material", "metal"] + flag)
            self.assertEqual(code, 0, err)
            with open(self.path("lean.json")) as handle:
                leans[bool(flag)] = json.load(handle)["orientation_lean_deg"]
        self.assertEqual(leans[True], 0.0)
        self.assertNotEqual(leans[False], 0.0)
        self.assertLess(abs(leans[False]), 1.0)

    def test_square_plan_flag(self):
        """--no-square-plan leaves every wall where its own poses fitted it: the stats count no
        wall turned and none put on a shared line, where by default they are counted (the
        rule itself: qa_wall_fusion.test_plan_squared_and_pieces_put_on_one_line)."""
        stats = {}
        for flag in ([], ["--no-square-plan"]):
            code, _, err = run([self.meta, "--geojson", self.path("square.geojson"), "--stats",
                                self.path("square.json"), "--quiet", "--material", "metal"] + flag)
            self.assertEqual(code, 0, err)
            with open(self.path("square.json")) as handle:
                stats[bool(flag)] = json.load(handle)
        self.assertEqual((stats[True]["walls_squared"], stats[True]["walls_on_shared_lines"]), (0, 0))
        self.assertIsInstance(stats[False]["walls_squared"], int)
        self.assertIsInstance(stats[False]["walls_on_shared_lines"], int)

    def test_rx_calibration(self):
        """The reference frames give the chains' relative responses: after the correction the
        chains differ by less than 0.01 dB and 0.1 degree, and the DC offset is removed."""
        sv = survey.read_survey(self.meta)
        cal = rx_calibration.calibrate_survey(sv)
        self.assertIsNotNone(cal)
        corrected = self.res.rx_chain_gains * cal.correction
        relative = corrected / corrected.mean(axis=0)
        self.assertLess(np.max(np.abs(20 * np.log10(np.abs(relative)))), 0.01)
        self.assertLess(np.max(np.abs(np.degrees(np.angle(relative)))), 0.1)
        sc = corridor_scene(self.null)
        self.assertLess(np.max(np.abs(cal.dc_offset - sc.impairments["dc_offset"])),
                        0.05 * np.max(np.abs(sc.impairments["dc_offset"])))
        true_delay = sc.impairments["rx"]["delay_s"] - sc.impairments["rx"]["delay_s"].mean()
        self.assertLess(np.max(np.abs(cal.delay_s - true_delay)), 1e-12)
        with self.assertRaisesRegex(ValueError, "NaN"):
            rx_calibration.calibrate_rx(np.full((1, 8, 64), np.nan, complex), sv.subcarrier_offsets_hz)

    def test_system_delay(self):
        """Without the TX null the direct path measures the system delay (free space: a survey
        with no walls, which maps to no walls); with the null it cannot, and the tool says what
        to give instead."""
        ones_meta, _, _ = write(corridor_scene("ones", impaired=False, known_delay=False, walls=False),
                                self.tmp.name, "ones")
        fused, info = cli_map.map_survey(survey.read_survey(ones_meta), settings=cli_map.jade_settings(paths=4),
                                         keep_results=True)
        self.assertEqual(info["system_delay"], "measured on the direct path")
        # what WallFusion.add was given, a pose group each, for scripts that map part again
        self.assertEqual(len(info["jade_results"]), fused.stats["poses"])
        np.testing.assert_array_equal([r[0] for r in info["jade_results"]], fused.odometry)
        self.assertAlmostEqual(info["system_delay_s"], 27e-9, delta=0.02e-9)
        self.assertEqual(fused.walls, [])
        evaluation.load_map(fused.to_geojson())
        nulled_meta, _, _ = write(corridor_scene(self.null, impaired=False, known_delay=False), self.tmp.name, "nulled")
        code, _, err = run([nulled_meta, "--geojson", self.path("nulled.geojson"), "--quiet"])
        self.assertEqual(code, 2)
        self.assertIn("--system-delay-s", err)
        code, _, err = run([nulled_meta, "--geojson", self.path("nulled.geojson"), "--quiet", "--system-delay-s", "27e-9"])
        self.assertEqual(code, 0, err)

    def test_bad_arguments(self):
        code, _, err = run([self.path("missing.sigmf-meta"), "--geojson", self.path("x.geojson"), "--quiet"])
        self.assertEqual(code, 2)
        self.assertIn("sigmf-meta", err)
        code, _, err = run([self.meta, "--geojson", self.path("x.geojson"), "--ros-resolution", "0", "--quiet"])
        self.assertEqual(code, 2)
        self.assertIn("--ros-resolution", err)
        code, _, err = run([self.meta, "--geojson", self.path("x.geojson"), "--material", "plaster", "--quiet"])
        self.assertEqual(code, 2)
        self.assertIn("unknown preset", err)


    def test_survey_driven_down_and_back(self):
        """A survey down the corridor and back (8 poses out, one at the turn, 8 back): the
        fusion maps one pass at a time, so thrumapper-map refuses it whole with an error that
        names the pose group where the track turns and the --poses that map each pass; so
        picked, each pass maps the wall on its face (the way back at heading π); with --passes
        both are mapped and merged into one map (the pose of the turn left out), the wall on its
        face."""
        meta, _, res = write(corridor_scene(self.null, back=True), self.tmp.name, "back")
        code, _, err = run([meta, "--geojson", self.path("back.geojson"), "--quiet"])
        self.assertEqual(code, 2)
        self.assertIn("the track turns at pose group 8 of 0-16", err)
        self.assertIn("--poses 0:8 and --poses 8:, or give --passes", err)
        self.assertFalse(os.path.exists(self.path("back.geojson")))
        for picked, count in (("0:8", 8), ("9:", 8)):
            out = self.path(f"back-{picked.replace(':', '_')}.geojson")
            code, _, err = run([meta, "--geojson", out, "--poses", picked, "--material", "metal", "--quiet"])
            self.assertEqual(code, 0, err)
            fused = evaluation.load_map(out)
            self.assertEqual(len(fused.trajectory), count)
            points = np.vstack([d["points"] for d in fused.detections])
            self.assertLess(float(np.max(np.abs(points[:, 1] + 0.701))), 0.03)
        # --passes: both passes mapped and merged into one map, the turn's own pose left out
        out = self.path("back-passes.geojson")
        code, _, err = run([meta, "--geojson", out, "--passes", "--material", "metal", "--quiet",
                            "--stats", self.path("back-passes.json")])
        self.assertEqual(code, 0, err)
        fused = evaluation.load_map(out)
        self.assertEqual(len(fused.trajectory), 16)
        walls = [w for w in fused.walls if w["class"] == "line_of_sight"]
        self.assertTrue(walls)
        for w in walls:
            self.assertLess(float(np.max(np.abs(np.asarray(w["coordinates"])[:, 1] + 0.701))), 0.03, w)
        points = np.vstack([d["points"] for d in fused.detections])
        self.assertLess(float(np.max(np.abs(points[:, 1] + 0.701))), 0.03)
        with open(self.path("back-passes.json"), encoding="utf-8") as handle:
            stats = json.load(handle)
        self.assertEqual((len(stats["passes"]), stats["poses_in_turns"], stats["poses"]), (2, 1, 16))
        for bad, says in (("9", "expected FIRST:END"), ("a:b", "expected FIRST:END"), ("-1:", "start at 0"),
                          ("40:", "picks none of the survey's 17 pose groups")):
            code, _, err = run([meta, "--geojson", self.path("x.geojson"), f"--poses={bad}", "--quiet"])
            self.assertEqual(code, 2, bad)
            self.assertIn(says, err)


if __name__ == "__main__":
    gr_unittest.run(qa_cli_map)
