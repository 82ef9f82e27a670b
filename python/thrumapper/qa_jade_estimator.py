#!/usr/bin/env python3
#
# SPDX-License-Identifier: GPL-3.0-or-later
#
"""QA of the jade_estimator block: frames in, spectra and path messages out."""

import gc
import math

import numpy as np
import pmt
from gnuradio import blocks, gr, gr_unittest

from gnuradio import thrumapper
from gnuradio.thrumapper.testing import wait_for

C = thrumapper.speed_of_light_m_s




def model_frame(radar, paths, noise_std=0.0, rng=None):
    """One M×N CSI frame from the far-field model: Σ γ a(θ)⊗g(τ) (+ complex noise)."""
    m, n = radar.num_rx, radar.num_subcarriers
    h = np.zeros(m * n, complex)
    for aoa_deg, delay_s, gain in paths:
        h += gain * np.asarray(thrumapper.space_time_manifold(radar, math.radians(aoa_deg), delay_s))
    if noise_std:
        h += noise_std / math.sqrt(2) * (rng.standard_normal(m * n) + 1j * rng.standard_normal(m * n))
    return h.astype(np.complex64)


class qa_jade_estimator(gr_unittest.TestCase):
    def setUp(self):
        self.tb = gr.top_block()
        self.radar = thrumapper.radar_description.make_uca_pair(subcarriers=64)
        self.vlen = self.radar.num_rx * self.radar.num_subcarriers

    def tearDown(self):
        self.tb = None
        gc.collect()  # the flowgraph's cycles freed here, not in a later test's block thread (qa_radio_chain)

    def run_frames(self, frames, est, tags=()):
        src = blocks.vector_source_c(np.concatenate(frames).tolist(), False, self.vlen, list(tags))
        spectra = blocks.vector_sink_f(est.num_angles() * est.num_delays())
        msgs = blocks.message_debug()
        self.tb.connect(src, est, spectra)
        self.tb.msg_connect(est, "paths", msgs, "store")
        self.tb.run()
        self.tb.msg_disconnect(est, "paths", msgs, "store")
        return spectra, msgs

    def test_paths_message_and_spectrum(self):
        rng = np.random.default_rng(4)
        # two walls on the right-hand side, as in §4.3: the corridor wall and one behind it
        truth = [(268.0, 5.2e-9, 1.0), (284.0, 15.3e-9, 0.2)]
        frames = [model_frame(self.radar, truth, 0.01, rng) for _ in range(3)]
        est = thrumapper.jade_estimator(self.radar, num_angles=180, num_delays=81,
                                        delay_min_s=0, delay_max_s=40e-9, max_paths=4)
        rx_time = pmt.make_tuple(pmt.from_uint64(1700000000), pmt.from_double(0.25))
        tags = [gr.tag_utils.python_to_tag((1, pmt.intern("rx_time"), rx_time)),
                gr.tag_utils.python_to_tag((1, pmt.intern("frame_index"), pmt.from_uint64(41)))]
        spectra, msgs = self.run_frames(frames, est, tags)
        self.assertTrue(wait_for(lambda: msgs.num_messages() == 3))
        self.assertEqual(est.num_estimated(), 3)
        self.assertEqual(len(spectra.data()), 3 * 180 * 81)
        for i in range(3):
            msg = msgs.get_message(i)
            self.assertTrue(pmt.is_dict(msg))
            paths = pmt.dict_ref(msg, pmt.intern("paths"), pmt.PMT_NIL)
            self.assertEqual(pmt.length(paths), 2)
            found = [(pmt.to_double(pmt.dict_ref(pmt.vector_ref(paths, k), pmt.intern("angle_deg"), pmt.PMT_NIL)),
                      pmt.to_double(pmt.dict_ref(pmt.vector_ref(paths, k), pmt.intern("delay_s"), pmt.PMT_NIL)))
                     for k in range(2)]
            # strongest first: the corridor wall
            self.assertAlmostEqual(found[0][0], 268.0, delta=0.5)
            self.assertAlmostEqual(found[0][1] * 1e9, 5.2, delta=0.05)
            self.assertAlmostEqual(found[1][0], 284.0, delta=2.0)
            self.assertAlmostEqual(found[1][1] * 1e9, 15.3, delta=0.3)
        # the tagged frame carries its own index and time; the others count on from it
        second = msgs.get_message(1)
        self.assertEqual(pmt.to_uint64(pmt.dict_ref(second, pmt.intern("frame_index"), pmt.PMT_NIL)), 41)
        self.assertTrue(pmt.equal(pmt.dict_ref(second, pmt.intern("rx_time"), pmt.PMT_NIL), rx_time))
        self.assertFalse(pmt.dict_has_key(msgs.get_message(0), pmt.intern("rx_time")))
        third = msgs.get_message(2)
        self.assertEqual(pmt.to_uint64(pmt.dict_ref(third, pmt.intern("frame_index"), pmt.PMT_NIL)), 42)
        # the spectrum's highest cell is next to the strongest path
        s = np.array(spectra.data()[:180 * 81]).reshape(180, 81)
        a, d = np.unravel_index(np.argmax(s), s.shape)
        self.assertLess(abs(a * 2.0 - 268.0), 3.0)
        self.assertLess(abs(d * 0.5e-9 - 5.2e-9), 1.0e-9)

    def test_csi_attached_only_when_asked(self):
        """attach_csi: the message carries the frame as estimated, bit for bit, and the system
        delay; no weights when the frame has no weights tag. Off (the default): no CSI."""
        frame = model_frame(self.radar, [(250.0, 6.0e-9, 1.0)])
        est = thrumapper.jade_estimator(self.radar, num_angles=90, num_delays=41, system_delay_s=7e-9)
        self.assertFalse(est.attach_csi())
        _, msgs = self.run_frames([frame], est)
        self.assertFalse(pmt.dict_has_key(msgs.get_message(0), pmt.intern("csi")))
        self.tb = gr.top_block()
        est = thrumapper.jade_estimator(self.radar, num_angles=90, num_delays=41, system_delay_s=7e-9, attach_csi=True)
        self.assertTrue(est.attach_csi())
        _, msgs = self.run_frames([frame, frame], est)
        self.assertEqual(msgs.num_messages(), 2)
        msg = msgs.get_message(1)
        csi = np.asarray(pmt.c32vector_elements(pmt.dict_ref(msg, pmt.intern("csi"), pmt.PMT_NIL)), np.complex64)
        self.assertTrue(np.array_equal(csi, frame))
        self.assertEqual(pmt.to_double(pmt.dict_ref(msg, pmt.intern("system_delay_s"), pmt.PMT_NIL)), 7e-9)
        self.assertFalse(pmt.dict_has_key(msg, pmt.intern("tx_weights")))
        self.assertFalse(pmt.to_bool(pmt.dict_ref(msg, pmt.intern("direct_path_cancelled"), pmt.PMT_NIL)))
        est.set_attach_csi(False)
        self.assertFalse(est.attach_csi())

    def test_system_delay_is_removed(self):
        tsys = 23.0e-9
        frame = model_frame(self.radar, [(90.0, 4.0e-9 + tsys, 1.0)])
        est = thrumapper.jade_estimator(self.radar, num_angles=90, num_delays=41,
                                        delay_max_s=20e-9, max_paths=1, system_delay_s=tsys)
        _, msgs = self.run_frames([frame], est)
        self.assertTrue(wait_for(lambda: msgs.num_messages() == 1))
        paths = pmt.dict_ref(msgs.get_message(0), pmt.intern("paths"), pmt.PMT_NIL)
        delay = pmt.to_double(pmt.dict_ref(pmt.vector_ref(paths, 0), pmt.intern("delay_s"), pmt.PMT_NIL))
        self.assertAlmostEqual(delay, 4.0e-9, delta=1e-12)

    def test_bad_frames_skipped_and_counted(self):
        rng = np.random.default_rng(9)
        good = model_frame(self.radar, [(45.0, 6e-9, 1.0)], 0.01, rng)
        nan = good.copy()
        nan[17] = np.nan
        inf = good.copy()
        inf[3] = np.inf
        zero = np.zeros_like(good)
        est = thrumapper.jade_estimator(self.radar, num_angles=90, num_delays=41)
        spectra, msgs = self.run_frames([good, nan, zero, inf, good], est)
        self.assertTrue(wait_for(lambda: msgs.num_messages() == 2))
        self.assertEqual(est.num_skipped(), 3)
        self.assertEqual(est.num_estimated(), 2)
        self.assertEqual(len(spectra.data()), 2 * 90 * 41)
        # the frame counter still counts the skipped frames: the last good frame is index 4
        last = msgs.get_message(1)
        self.assertEqual(pmt.to_uint64(pmt.dict_ref(last, pmt.intern("frame_index"), pmt.PMT_NIL)), 4)

    def test_setters_and_bad_parameters(self):
        est = thrumapper.jade_estimator(self.radar, num_angles=90, num_delays=41)
        est.set_max_paths(2)
        self.assertEqual(est.max_paths(), 2)
        est.set_smoothing_window(30)
        self.assertEqual(est.smoothing_window(), 30)
        est.set_system_delay(1e-9)
        self.assertEqual(est.system_delay(), 1e-9)
        est.set_delay_span(0, 30e-9)
        est.set_angle_span(180, 360)
        with self.assertRaisesRegex(ValueError, "smoothing_window"):
            est.set_smoothing_window(64)
        with self.assertRaisesRegex(ValueError, "max_paths"):
            est.set_max_paths(0)
        with self.assertRaisesRegex(ValueError, "delay_max_s"):
            est.set_delay_span(10e-9, 5e-9)
        with self.assertRaisesRegex(ValueError, "num_angles"):
            thrumapper.jade_estimator(self.radar, num_angles=1)
        with self.assertRaisesRegex(ValueError, "radar description"):
            thrumapper.jade_estimator(None)

    def test_wrong_vector_size_refused_at_connect(self):
        est = thrumapper.jade_estimator(self.radar, num_angles=90, num_delays=41)
        src = blocks.vector_source_c([0j] * (self.vlen - 8), False, self.vlen - 8)
        with self.assertRaises(Exception):
            self.tb.connect(src, est)


if __name__ == "__main__":
    gr_unittest.run(qa_jade_estimator)
