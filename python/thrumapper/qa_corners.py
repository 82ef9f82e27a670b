#!/usr/bin/env python3
#
# SPDX-License-Identifier: GPL-3.0-or-later
#
"""Corner candidates on the simulated §4.4–4.5 corridor scan, and none along a plain wall."""

import os
import tempfile

import numpy as np
from gnuradio import gr_unittest

from gnuradio.thrumapper import building_sim, corners, jade_pipeline, scene, survey

SCENES = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "examples", "scenes")


def run(sc):
    res = building_sim.simulate_survey(sc, progress=False)
    with tempfile.TemporaryDirectory() as d:
        meta = survey.write_survey(
            os.path.join(d, "s"), res.csi, subcarrier_offsets_hz=sc.radar.subcarrier_offsets_hz,
            center_frequency_hz=sc.radar.carrier_hz, rx_elements_m=sc.radar.rx_elements_m,
            tx_elements_m=sc.radar.tx_elements_m, tx_weights=res.tx_weights, poses=res.poses_true,
            frame_types=res.frame_types, system_delay_s=sc.impairments["system_delay_s"])
        sv = survey.read_survey(meta)
        return list(jade_pipeline.run_survey(sv, jade_pipeline.JadeSettings(max_paths=4, stages=2)))


class qa_corners(gr_unittest.TestCase):
    def test_corridor_corner_flagged(self):
        sc = scene.load_scene(os.path.join(SCENES, "paper_4_4_corridor_corner.yaml"))
        results = run(sc)
        found = corners.find_corner_candidates(results, sc.radar.tx_centre_m, sc.radar.rx_centre_m)
        truth = [np.asarray(f["geometry"]["coordinates"]) for f in building_sim.truth_geojson(sc)["features"]
                 if f["properties"]["kind"] == "corner"]
        self.assertGreaterEqual(len(found), 1)
        for c in found:
            # every candidate is a real corner; the plasterboard's reflection group delay (about
            # -0.7 ns a bounce, two bounces) pulls the located apex ~0.3 m toward the robot
            self.assertLess(min(np.hypot(*(c.point_m - t)) for t in truth), 0.45)
            self.assertLess(c.spread_m, 0.15)
            self.assertGreaterEqual(c.travel_span_m, 0.5)
        # its bearing from the TX can be nulled: a bearing in [0, 360)
        b = found[0].bearing_from_tx_deg(results[found[0].pose_indices[0]]["pose"], sc.radar.tx_centre_m)
        self.assertTrue(0 <= b < 360)

    def test_plain_wall_gives_no_candidate(self):
        sc = scene.load_scene({
            "name": "wall", "seed": 4,
            "radar": {"elements": 8, "radius_m": 0.08, "baseline_m": 0.7, "carrier_hz": 2.44e9,
                      "bandwidth_hz": 120e6, "subcarriers": 64},
            "walls": [{"segment": [[-20, -1.2], [20, -1.2]], "material": "metal"}],
            "trajectory": {"waypoints": [[0, 0], [2.0, 0]], "step_m": 0.25},
            "frames_per_pose": 2, "noise": {"power_db": -100},
            "impairments": {"system_delay_s": 20e-9, "system_delay_known": True}})
        results = run(sc)
        self.assertEqual(corners.find_corner_candidates(results, sc.radar.tx_centre_m, sc.radar.rx_centre_m), [])

    def test_bad_input(self):
        with self.assertRaisesRegex(ValueError, "pose"):
            corners.locate_paths([{"pose": [0, float("nan"), 0], "paths": []}], [-0.35, 0], [0.35, 0])
        self.assertEqual(corners.find_corner_candidates([], [-0.35, 0], [0.35, 0]), [])


if __name__ == "__main__":
    gr_unittest.run(qa_corners)
