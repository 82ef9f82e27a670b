#!/usr/bin/env python3
#
# SPDX-License-Identifier: GPL-3.0-or-later
#
"""TX chain calibration: the chains' errors recovered from single-element frames, the null
at the receiver restored, and the survey's calibration frames kept out of the survey."""

import contextlib
import io
import json
import math
import os
import tempfile

import numpy as np
import yaml
from gnuradio import gr_unittest

from gnuradio.thrumapper import building_sim, cli_beam, cli_sim, jade_pipeline, rx_calibration, survey, survey_blocks
from gnuradio.thrumapper import scene as scene_mod
from gnuradio.thrumapper import tx_calibration

C = 299792458.0
NOTHING = {"direct": False, "reflections": False, "second_order": False, "diffuse": False, "edges": False,
           "clutter": False}
GAINS_DB = [0.0, 0.15, -0.1, 0.05, -0.2, 0.1, 0.0, -0.05]
PHASES_DEG = [0.0, 2.5, -1.5, 3.0, -2.0, 1.0, -3.5, 0.5]
DELAYS_PS = [0.0, 2.0, -3.0, 1.0, 0.0, -2.0, 4.0, -1.0]
NULL_STEER = {"mode": "null_steer", "main_lobe_deg": 270, "wavefront": "spherical", "null_depth_db": 40}
# A corridor 2.15 m wide, plasterboard: its walls' echoes come 21 dB below the direct path,
# 4.7 ns after it.
CORRIDOR = [{"segment": [[-3.0, -1.075], [6.0, -1.075]], "material": "plasterboard"},
            {"segment": [[-3.0, 1.075], [6.0, 1.075]], "material": "plasterboard"}]


def _scene(walls, physics, poses, **extra):
    data = {"name": "txcal", "seed": 5, "radar": {}, "walls": walls,
            "trajectory": {"poses": [list(p) for p in poses]}, "physics": {**NOTHING, **physics},
            "noise": {"power_db": -120}, "tx_weights": NULL_STEER,
            "impairments": {"tx": {"gain_db": GAINS_DB, "phase_deg": PHASES_DEG, "delay_ps": DELAYS_PS}}}
    for key, value in extra.items():
        if isinstance(value, dict) and isinstance(data.get(key), dict):
            data[key] = {**data[key], **value}
        else:
            data[key] = value
    return data


def _relative(values):
    values = np.asarray(values, float)
    return values - values.mean()


def _carrier_phases(carrier_hz):
    """The chains' phases at the carrier: φ_k − 2π·fc·δ_k (α_k(f) = g·e^{jφ}·e^{−j2πfδ})."""
    return np.radians(PHASES_DEG) - 2 * math.pi * carrier_hz * np.array(DELAYS_PS) * 1e-12


def _phase_error_deg(calibration, truth_phase_rad):
    error = np.angle(np.exp(1j * (calibration.phase_rad - truth_phase_rad)))
    return np.degrees(error - error.mean())


def _single_element_frames(scene, pose_indices):
    """Noiseless frames (R, M, N) of each element alone at these poses, through the TX chains."""
    radar = scene.radar
    alpha = building_sim.chain_gains(scene.impairments["tx"], radar.frequencies_hz)
    frames, elements, places = [], [], []
    for p in pose_indices:
        mimo = building_sim.channel_matrix_at_pose(scene, scene.poses[p])  # (K, M, N)
        frames.append(alpha[:, None, :] * mimo)
        elements.append(np.arange(radar.num_tx))
        places.append(np.full(radar.num_tx, p))
    return np.concatenate(frames), np.concatenate(elements), np.concatenate(places)


class qa_tx_calibration(gr_unittest.TestCase):
    def test_single_element(self):
        self.assertEqual(tx_calibration.single_element([0, 0, 0.5j, 0]), 2)
        self.assertEqual(tx_calibration.single_element([1e-12, 0, 1.0, 0]), 2)
        self.assertEqual(tx_calibration.single_element([1, 1, 0, 0]), -1)
        self.assertEqual(tx_calibration.single_element([0, 0, 0, 0]), -1)
        self.assertEqual(tx_calibration.single_element([np.nan, 1, 0, 0]), -1)

    def test_direct_path_model_is_free_space(self):
        # One TX and one RX element 0.7 m apart: λ/(4π·0.7) in amplitude, 0.7 m / c in delay.
        f = np.array([2.38e9, 2.44e9, 2.50e9])
        d = tx_calibration.element_direct_paths([[-0.35, 0.0]], [[0.35, 0.0]], f)[0, 0]
        np.testing.assert_allclose(np.abs(d), C / f / (4 * math.pi * 0.7), rtol=1e-12)
        slope = np.diff(np.unwrap(np.angle(d))) / np.diff(f)
        np.testing.assert_allclose(slope, -2 * math.pi * 0.7 / C, rtol=1e-9)

    def test_recovers_chain_errors_in_free_space(self):
        # Direct path only: the relative gains, phases and delays come back to within what
        # the noise (75 dB below the direct path) allows.
        data = _scene([], {"direct": True}, [[0.0, 0.0, 0.0]],
                      impairments={"tx_calibration_frames": 2, "system_delay_s": 31e-9})
        result = building_sim.simulate_survey(scene_mod.load_scene(data), progress=False)
        cal = result.tx_calibration
        self.assertIsNotNone(cal)
        np.testing.assert_allclose(cal.gain_db, _relative(GAINS_DB), atol=0.002)
        self.assertLess(np.max(np.abs(_phase_error_deg(cal, _carrier_phases(cal.carrier_hz)))), 0.02)
        np.testing.assert_allclose(cal.delay_s, _relative(DELAYS_PS) * 1e-12, atol=0.05e-12)
        np.testing.assert_array_equal(cal.frames_per_element, [2] * 8)

    def test_corridor_echoes_removed(self):
        # The corridor walls' echoes are the same at every pose along it: without their
        # removal they leave about a degree in the phases; with it, a few hundredths.
        scene = scene_mod.load_scene(_scene(CORRIDOR, {"direct": True, "reflections": True},
                                            [[0.0, 0.0, 0.0], [0.2, 0.0, 0.0]]))
        radar = scene.radar
        frames, elements, places = _single_element_frames(scene, [0, 1])
        truth = _carrier_phases(radar.carrier_hz)
        args = (frames, elements, np.ones(elements.size), radar.tx_elements_m, radar.rx_elements_m,
                radar.carrier_hz, radar.subcarrier_offsets_hz)
        plain = tx_calibration.calibrate_tx(*args, poses=places, max_echoes=0)
        fitted = tx_calibration.calibrate_tx(*args, poses=places)
        plain_rms = float(np.sqrt(np.mean(_phase_error_deg(plain, truth) ** 2)))
        fitted_rms = float(np.sqrt(np.mean(_phase_error_deg(fitted, truth) ** 2)))
        self.assertGreater(plain_rms, 0.3)
        self.assertLess(fitted_rms, 0.05)
        self.assertLess(np.max(np.abs(fitted.gain_db - _relative(GAINS_DB))), 0.01)

        # The null at the receiver: the weights corrected with the estimate put it back to
        # within a few dB of the nominal design, where the raw chains fill it by 20 dB or more.
        weights = building_sim.scene_tx_weights(scene)
        alpha = building_sim.chain_gains(scene.impairments["tx"], radar.frequencies_hz)
        depth = lambda chains: tx_calibration.null_depth_db(  # noqa: E731
            weights, radar.tx_elements_m, radar.rx_elements_m, radar.frequencies_hz, chains)
        nominal, raw = depth(None), depth(alpha)
        corrected = depth(alpha * fitted.correction[:, None])
        self.assertGreater(raw - nominal, 20.0)
        self.assertLess(corrected - nominal, 3.0)
        np.testing.assert_allclose(fitted.corrected_weights(weights), weights * fitted.correction)

    def test_bad_input(self):
        radar = scene_mod.load_scene(_scene([], {"direct": True}, [[0, 0, 0]])).radar
        geometry = (radar.tx_elements_m, radar.rx_elements_m, radar.carrier_hz, radar.subcarrier_offsets_hz)
        good = np.ones((8, 8, 128), complex)
        elements = np.arange(8)
        cases = [
            ((np.ones((8, 8, 64)), elements, np.ones(8)), "expected frames"),
            ((np.where(np.arange(128) == 5, np.nan, good), elements, np.ones(8)), "NaN"),
            ((good, np.arange(8) % 7, np.ones(8)), "no frame sounds TX element(s) [7]"),
            ((good, elements, np.zeros(8)), "non-zero"),
            ((good, elements + 1, np.ones(8)), "element indices"),
            ((good, elements[:5], np.ones(8)), "5 elements"),
        ]
        for args, words in cases:
            with self.assertRaises(ValueError) as ctx:
                tx_calibration.calibrate_tx(*args, *geometry)
            self.assertIn(words, str(ctx.exception))
        with self.assertRaises(ValueError) as ctx:
            tx_calibration.calibrate_tx(good, elements, np.ones(8), *geometry, poses=[0, 1])
        self.assertIn("pose labels", str(ctx.exception))
        with self.assertRaises(ValueError) as ctx:
            tx_calibration.calibrate_tx(good, elements, np.ones(8), *geometry, poses=[0, 0, 0, 0, 1, 1, 1, 1])
        self.assertIn("no pose where every TX element", str(ctx.exception))
        cal = tx_calibration.calibrate_tx(np.ones((8, 8, 128)) * (1 + np.arange(8))[:, None, None], elements,
                                          np.ones(8), *geometry, max_echoes=0)
        with self.assertRaises(ValueError) as ctx:
            cal.corrected_weights([1, 2, 3])
        self.assertIn("3 weights for a calibration of 8", str(ctx.exception))

    def test_survey_with_calibration_frames(self):
        # thrumapper-sim writes the calibration frames into the survey, with their weights;
        # the tools read them back, keep them out of the pose groups and the replayed
        # survey, and measure the system delay on them (the survey's own frames are nulled).
        data = _scene(CORRIDOR, {"direct": True, "reflections": True},
                      [[0.0, 0.0, 0.0], [0.2, 0.0, 0.0], [0.4, 0.0, 0.0]], frames_per_pose=2,
                      impairments={"tx_calibration_poses": 2, "system_delay_s": 31e-9,
                                   "system_delay_known": False,
                                   "rx": {"gain_db_std": 0.3, "phase_deg_std": 20, "delay_ps_std": 10}})
        with tempfile.TemporaryDirectory() as tmp:
            path = os.path.join(tmp, "txcal.yaml")
            with open(path, "w", encoding="utf-8") as handle:
                yaml.safe_dump(data, handle)
            out = io.StringIO()
            with contextlib.redirect_stdout(out), contextlib.redirect_stderr(io.StringIO()):
                self.assertEqual(cli_sim.main([path, "--out", tmp, "--tx-calibration-frames", "2"]), 0)
            self.assertIn("TX calibration from 32 single-element frames", out.getvalue())
            self.assertIn("null at the receiver", out.getvalue())
            sv = survey.read_survey(os.path.join(tmp, "txcal.sigmf-meta"))
            scene = scene_mod.load_scene(data)  # without the calibration: the same weights
            weights = building_sim.scene_tx_weights(scene)
            np.testing.assert_allclose(sv.tx_weights, weights, rtol=1e-6)  # the nominal weights

            frames, elements = tx_calibration.single_element_frames(sv)
            self.assertEqual(frames.size, 8 * 2 * 2)
            np.testing.assert_array_equal(np.bincount(elements), [4] * 8)
            self.assertTrue(np.all(np.isfinite(sv.poses[frames])))
            groups = survey.group_frames_by_pose(sv)
            self.assertEqual(len(groups), 3)
            self.assertEqual([len(g) for g, _ in groups], [2, 2, 2])
            self.assertFalse(set(frames) & set(np.concatenate([g for g, _ in groups]).tolist()))

            # The calibration the tools measure from the file is the simulator's.
            rx_cal = rx_calibration.calibrate_survey(sv)
            cal = tx_calibration.calibrate_survey_tx(sv, rx_cal)
            self.assertLess(np.max(np.abs(_phase_error_deg(cal, _carrier_phases(cal.carrier_hz)))), 0.1)

            # The system delay, not in the file, from the calibration frames' direct paths.
            self.assertIsNone(sv.system_delay_s)
            delay = jade_pipeline.estimate_system_delay(sv, groups)
            self.assertAlmostEqual(delay, 31e-9, delta=0.05e-9)

            # thrumapper-beam measures the chains from the file and saves the correction,
            # which usrp_survey.grc loads; the weights it prints are the design's over them.
            meta = os.path.join(tmp, "txcal.sigmf-meta")
            saved = os.path.join(tmp, "tx_calibration.json")
            out = io.StringIO()
            with contextlib.redirect_stdout(out):
                self.assertEqual(cli_beam.main(["--main-lobe-deg", "270", "--tx-calibration", meta, "--save", saved,
                                                "--json"]), 0)
            report = json.loads(out.getvalue())
            correction = tx_calibration.load_correction(saved, 8)
            design = np.array([complex(*w) for w in report["weights"]])
            sent = np.array([complex(*w) for w in report["corrected_weights"]])
            np.testing.assert_allclose(sent, design * correction, rtol=1e-12)
            self.assertGreater(report["coupling_uncorrected_db"], report["coupling_db"] + 10.0)
            self.assertAlmostEqual(report["tx_calibration"]["phase_deg"][3] - report["tx_calibration"]["phase_deg"][0],
                                   math.degrees(_carrier_phases(sv.center_frequencies_hz[0])[3]
                                                - _carrier_phases(sv.center_frequencies_hz[0])[0]), delta=0.1)

            source = survey_blocks.survey_source(os.path.join(tmp, "txcal.sigmf-meta"))
            self.assertEqual(len(source._frames), 6)
            everything = survey_blocks.survey_source(os.path.join(tmp, "txcal.sigmf-meta"), frame_types="all")
            self.assertEqual(len(everything._frames), sv.num_frames)

    def test_correction_file_errors(self):
        with tempfile.TemporaryDirectory() as tmp:
            def write(text):
                path = os.path.join(tmp, f"c{len(os.listdir(tmp))}.json")
                with open(path, "w", encoding="utf-8") as handle:
                    handle.write(text)
                return path

            good = {"kind": "thrumapper_tx_calibration", "correction": [[1, 0]] * 8}
            cases = [
                (os.path.join(tmp, "missing.json"), "cannot read it"),
                (write("{not json"), "not JSON"),
                (write(json.dumps({"correction": [[1, 0]] * 8})), "not a TX calibration"),
                (write(json.dumps({**good, "correction": [[1, 0]] * 7})), "7 corrections for 8 TX elements"),
                (write(json.dumps({**good, "correction": [[1]] * 8})), "[re, im] pairs"),
                (write(json.dumps({**good, "correction": [[0, 0]] * 8})), "finite, non-zero"),
            ]
            for path, words in cases:
                with self.assertRaises(ValueError) as ctx:
                    tx_calibration.load_correction(path, 8)
                self.assertIn(words, str(ctx.exception))
            np.testing.assert_allclose(tx_calibration.load_correction(write(json.dumps(good)), 8), np.ones(8))
            # thrumapper-beam refuses a survey without single-element frames, and --save alone
            err = io.StringIO()
            with contextlib.redirect_stderr(err):
                self.assertEqual(cli_beam.main(["--save", os.path.join(tmp, "x.json")]), 2)
            self.assertIn("--save needs --tx-calibration", err.getvalue())

    def test_scene_fields(self):
        for value, words in ((-1, "tx_calibration_frames"), (1.5, "tx_calibration_frames")):
            with self.assertRaises(scene_mod.SceneError) as ctx:
                scene_mod.load_scene(_scene([], {"direct": True}, [[0, 0, 0]],
                                            impairments={"tx_calibration_frames": value}))
            self.assertIn(words, str(ctx.exception))
        with self.assertRaises(scene_mod.SceneError) as ctx:
            scene_mod.load_scene(_scene([], {"direct": True}, [[0, 0, 0]],
                                        impairments={"tx_calibration_poses": 0}))
        self.assertIn("tx_calibration_poses", str(ctx.exception))


if __name__ == "__main__":
    gr_unittest.run(qa_tx_calibration)
