#!/usr/bin/env python3
#
# SPDX-License-Identifier: GPL-3.0-or-later
#
"""QA of null_steering_weights, projection_canceller and JADE's successive cancellation,
against the simulated building's exact wideband channel."""

import gc
import math

import numpy as np
import pmt
from gnuradio import blocks, gr, gr_unittest

from gnuradio import thrumapper
from gnuradio.thrumapper import building_sim, scene
from gnuradio.thrumapper.testing import wait_for




def free_space_scene(**extra):
    data = {"name": "free", "seed": 1,
            "radar": {"elements": 8, "radius_m": 0.08, "baseline_m": 0.7, "carrier_hz": 2.44e9,
                      "bandwidth_hz": 120e6, "subcarriers": 64},
            "walls": [], "trajectory": {"poses_deg": [[0, 0, 0]]}, "frames_per_pose": 1,
            "noise": {"power": 0.0}}
    data.update(extra)
    return scene.load_scene(data)


def radar_of(sc):
    return thrumapper.radar_description.make(sc.radar.tx_elements_m, sc.radar.rx_elements_m,
                                             sc.radar.carrier_hz, list(sc.radar.subcarrier_offsets_hz))


class qa_interference_blocks(gr_unittest.TestCase):
    def setUp(self):
        self.tb = gr.top_block()

    def tearDown(self):
        self.tb = None
        gc.collect()  # the flowgraph's cycles freed here, not in a later test's block thread (qa_radio_chain)

    def test_null_is_40_db_deep_in_the_wideband_simulation(self):
        """The designed weights, applied in the simulator's exact wideband near-field channel
        (its own geometry code, not ours), leave the direct coupling >= 40 dB below a beam of
        equal power aimed at the receiver."""
        sc = free_space_scene()
        radar = radar_of(sc)
        ns = thrumapper.null_steering(radar)
        w = np.array(ns.design(math.radians(300), [], True))
        Hk = building_sim.channel_matrix_at_pose(sc, sc.poses[0])  # (K, M, N) per TX element
        coupling = np.einsum("k,kmn->mn", w, Hk)
        # the strongest coupling any weights of this power can make: the top singular value
        G = Hk.reshape(Hk.shape[0], -1).T  # (M·N) × K
        best = np.linalg.svd(G, compute_uv=False)[0] ** 2 * np.sum(np.abs(w) ** 2)
        depth_db = 10 * np.log10(np.sum(np.abs(coupling) ** 2) / best)
        self.assertLess(depth_db, -40.0)
        # and the core's own figure agrees with the simulator's to 0.5 dB
        self.assertAlmostEqual(ns.coupling_db(list(w)), depth_db, delta=0.5)

    def test_weights_block_message_and_pattern(self):
        radar = thrumapper.radar_description.make_uca_pair(subcarriers=64)
        blk = thrumapper.null_steering_weights(radar, main_lobe_deg=300, null_receiver=True,
                                               null_angles_deg=[200.0], num_angles=72,
                                               update_period_s=0.05)
        msgs = blocks.message_debug()
        head = blocks.head(gr.sizeof_float * 72, 3)
        sink = blocks.vector_sink_f(72)
        self.tb.msg_connect(blk, "weights", msgs, "store")
        self.tb.connect(blk, head, sink)
        self.tb.start()
        self.assertTrue(wait_for(lambda: msgs.num_messages() >= 1))
        self.tb.wait()
        msg = msgs.get_message(0)
        w = pmt.c32vector_elements(pmt.dict_ref(msg, pmt.intern("weights"), pmt.PMT_NIL))
        self.assertEqual(len(w), 8)
        self.assertLess(pmt.to_double(pmt.dict_ref(msg, pmt.intern("coupling_db"), pmt.PMT_NIL)), -40)
        pattern = np.array(sink.data()[:72])
        # main lobe near 300°, the corner null at 200° deep, the receiver (0°) low
        self.assertGreater(pattern[60], 5.0)               # 300° / 5° per bin
        self.assertLess(pattern[40], pattern[60] - 30.0)   # 200°
        self.assertLess(pattern[0], pattern[60] - 10.0)    # 0°: far field toward the receiver
        # setters: a new main lobe re-designs, bad ones raise and keep the old weights
        blk.set_main_lobe(270.0)
        with self.assertRaisesRegex(ValueError, "inside the main lobe"):
            blk.set_null_angles([272.0])
        with self.assertRaisesRegex(ValueError, "at most"):
            blk.set_null_angles([10, 40, 60, 80, 100, 120, 140])
        self.assertEqual(len(blk.weights()), 8)
        self.assertLess(blk.expected_coupling_db(5.0), blk.expected_coupling_db(1.0) + 0.0 + 20)
        self.assertGreater(blk.expected_coupling_db(5.0), blk.expected_coupling_db(1.0))

    def test_canceller_removes_direct_path_and_takes_messages(self):
        sc = free_space_scene()
        radar = radar_of(sc)
        ns = thrumapper.null_steering(radar)
        w = ns.design(math.radians(300), [], False)  # no receiver null: the direct path is strong
        tsys = 12e-9
        direct = np.asarray(thrumapper.direct_path_response(radar, w, tsys)).reshape(8, 64)
        wall = np.asarray(thrumapper.space_time_manifold(radar, math.radians(243.4), 5.22e-9 + tsys)).reshape(8, 64)
        frame = (direct + 0.01 * wall).astype(np.complex64).ravel()
        bad = frame.copy()
        bad[5] = np.nan
        canc = thrumapper.projection_canceller(radar, cancel_direct=True, system_delay_s=tsys)
        canc.set_tx_weights(w)
        src = blocks.vector_source_c(np.concatenate([frame, bad, frame]).tolist(), False, 8 * 64)
        sink = blocks.vector_sink_c(8 * 64)
        self.tb.connect(src, canc, sink)
        self.tb.run()
        out = np.array(sink.data()).reshape(-1, 8 * 64)
        self.assertEqual(out.shape[0], 2)
        self.assertEqual(canc.num_skipped(), 1)
        # the direct path is gone; what is left is the wall's echo projected off the direct
        # path's response (eq. 10 also removes the part of the echo along it)
        r = direct.ravel() / np.linalg.norm(direct)
        kept = 0.01 * (wall.ravel() - r * np.vdot(r, wall.ravel()))
        self.assertLess(np.linalg.norm(out[0] - kept), 1e-4 * np.linalg.norm(kept))
        self.assertGreater(np.linalg.norm(kept), 0.5 * np.linalg.norm(0.01 * wall))
        # messages: jade_estimator's form sets the paths; a malformed one is counted
        canc2 = thrumapper.projection_canceller(radar)
        path = pmt.make_dict()
        path = pmt.dict_add(path, pmt.intern("angle_deg"), pmt.from_double(243.4))
        path = pmt.dict_add(path, pmt.intern("delay_s"), pmt.from_double(5.22e-9))
        vec = pmt.make_vector(1, path)
        msg = pmt.dict_add(pmt.make_dict(), pmt.intern("paths"), vec)
        canc2._post(pmt.intern("paths"), msg)
        canc2._post(pmt.intern("paths"), pmt.from_long(3))
        canc2._post(pmt.intern("weights"), pmt.intern("nonsense"))
        src2 = blocks.vector_source_c(frame.tolist(), False, 8 * 64)
        sink2 = blocks.vector_sink_c(8 * 64)
        self.tb = gr.top_block()
        self.tb.connect(src2, canc2, sink2)
        self.tb.start()
        self.assertTrue(wait_for(lambda: canc2.rank() == 1 and canc2.num_bad_messages() == 2))
        self.tb.wait()

    def test_canceller_tags_the_weights_it_cancelled_and_jade_passes_them_on(self):
        """Three frames, each a direct path and a wall echo; the middle one sounded with other
        weights and tagged "tx_weights" (as survey_source tags an override). The canceller
        removes each frame's own direct path (the output is the echo alone, projected off it)
        and tags the weights it used as "direct_path_weights"; jade_estimator with attach_csi
        passes the frame it estimated on, the system delay and the frame's weights to
        wall_fusion in its message. Without cancel_direct no frame is tagged, and the message
        says the direct path is still in."""
        sc = free_space_scene()
        radar = radar_of(sc)
        ns = thrumapper.null_steering(radar)
        w1 = np.asarray(ns.design(math.radians(300), [], False))
        w2 = np.asarray(ns.design(math.radians(240), [], False))
        tsys = 12e-9
        wall = np.asarray(thrumapper.space_time_manifold(radar, math.radians(243.4), 5.22e-9 + tsys))
        frames, directs = [], []
        for w in (w1, w2, w1):
            d = np.asarray(thrumapper.direct_path_response(radar, list(w), tsys))
            directs.append(d)
            frames.append((d + 0.01 * wall).astype(np.complex64))
        override = gr.tag_utils.python_to_tag((1, pmt.intern("tx_weights"), pmt.init_c64vector(8, list(w2))))

        def run(cancel_direct):
            tb = gr.top_block()
            src = blocks.vector_source_c(np.concatenate(frames).tolist(), False, 8 * 64, [override])
            canc = thrumapper.projection_canceller(radar, cancel_direct=cancel_direct, system_delay_s=tsys)
            canc.set_tx_weights(list(w1))
            jade = thrumapper.jade_estimator(radar, 90, 0.0, 360.0, 41, 0.0, 40e-9, 2, 0, tsys, 1, True)
            # a vector sink keeps every tag (tag_debug's current_tags() holds the last work call's)
            tags = blocks.vector_sink_c(8 * 64)
            msgs = blocks.message_debug()
            tb.connect(src, canc, jade, blocks.null_sink(gr.sizeof_float * 90 * 41))
            tb.connect(canc, tags)
            tb.msg_connect(jade, "paths", msgs, "store")
            tb.run()
            self.assertTrue(wait_for(lambda: msgs.num_messages() == 3))
            weights_tags = [t for t in tags.tags() if pmt.symbol_to_string(t.key) == "direct_path_weights"]
            return weights_tags, [msgs.get_message(i) for i in range(3)]

        tagged, messages = run(True)
        self.assertEqual([t.offset for t in tagged], [0, 1, 2])
        for t, w, d, msg, frame in zip(tagged, (w1, w2, w1), directs, messages, frames):
            self.assertTrue(np.allclose(pmt.c32vector_elements(t.value), w, atol=1e-6))
            csi = np.asarray(pmt.c32vector_elements(pmt.dict_ref(msg, pmt.intern("csi"), pmt.PMT_NIL)))
            r = d / np.linalg.norm(d)
            echo = 0.01 * (wall - r * np.vdot(r, wall))  # the frame's own direct path is gone
            self.assertLess(np.linalg.norm(csi - echo), 1e-3 * np.linalg.norm(echo))
            weights = pmt.dict_ref(msg, pmt.intern("tx_weights"), pmt.PMT_NIL)
            values = pmt.c64vector_elements(weights) if pmt.is_c64vector(weights) else pmt.c32vector_elements(weights)
            self.assertTrue(np.allclose(values, w, atol=1e-6))
            self.assertAlmostEqual(pmt.to_double(pmt.dict_ref(msg, pmt.intern("system_delay_s"), pmt.PMT_NIL)), tsys)
            self.assertTrue(pmt.to_bool(pmt.dict_ref(msg, pmt.intern("direct_path_cancelled"), pmt.PMT_NIL)))

        tagged, messages = run(False)
        self.assertEqual(len(tagged), 0)
        for msg, frame in zip(messages, frames):
            self.assertFalse(pmt.to_bool(pmt.dict_ref(msg, pmt.intern("direct_path_cancelled"), pmt.PMT_NIL)))
            csi = np.asarray(pmt.c32vector_elements(pmt.dict_ref(msg, pmt.intern("csi"), pmt.PMT_NIL)))
            self.assertTrue(np.array_equal(csi, frame))

    def test_successive_cancellation_in_the_block(self):
        """jade_estimator with stages: each path's stage is in the message."""
        radar = thrumapper.radar_description.make_uca_pair(subcarriers=128)
        rng = np.random.default_rng(5)
        h = np.zeros(8 * 128, complex)
        for aoa, delay, gain in [(243.4, 5.22e-9, 1.0), (120.0, 8e-9, 0.3), (30.0, 11e-9, 0.2),
                                 (262.0, 15.2e-9, 10 ** -1.5)]:
            h += gain * np.asarray(thrumapper.space_time_manifold(radar, math.radians(aoa), delay))
        h += math.sqrt(1e-6 / 2) * (rng.standard_normal(h.size) + 1j * rng.standard_normal(h.size))
        est = thrumapper.jade_estimator(radar, num_angles=360, num_delays=200, max_paths=3, stages=3)
        src = blocks.vector_source_c(h.astype(np.complex64).tolist(), False, 8 * 128)
        msgs = blocks.message_debug()
        self.tb.connect(src, est, blocks.null_sink(gr.sizeof_float * 360 * 200))
        self.tb.msg_connect(est, "paths", msgs, "store")
        self.tb.run()
        self.assertTrue(wait_for(lambda: msgs.num_messages() == 1))
        paths = pmt.dict_ref(msgs.get_message(0), pmt.intern("paths"), pmt.PMT_NIL)
        found = []
        for i in range(pmt.length(paths)):
            d = pmt.vector_ref(paths, i)
            found.append((pmt.to_double(pmt.dict_ref(d, pmt.intern("angle_deg"), pmt.PMT_NIL)),
                          pmt.to_double(pmt.dict_ref(d, pmt.intern("delay_s"), pmt.PMT_NIL)),
                          pmt.to_long(pmt.dict_ref(d, pmt.intern("stage"), pmt.PMT_NIL))))
        hidden = [f for f in found if abs(f[0] - 262.0) < 1.0 and abs(f[1] - 15.2e-9) < 0.3e-9]
        self.assertEqual(len(hidden), 1)
        self.assertEqual(hidden[0][2], 1)  # the second stage
        self.assertEqual(est.stages(), 3)
        with self.assertRaisesRegex(ValueError, "stages"):
            est.set_stages(0)


class qa_cli_beam(gr_unittest.TestCase):
    def run_cli(self, *args):
        import subprocess
        import sys
        return subprocess.run([sys.executable, "-m", "gnuradio.thrumapper.cli_beam", *args],
                              capture_output=True, text=True, timeout=120)

    def test_design_json_and_png(self):
        import json
        import os
        import tempfile
        with tempfile.TemporaryDirectory() as tmp:
            png = os.path.join(tmp, "beam.png")
            out = self.run_cli("--main-lobe-deg", "300", "--null-deg", "200", "--json", "--png", png)
            self.assertEqual(out.returncode, 0, out.stderr)
            report = json.loads(out.stdout)
            self.assertEqual(len(report["weights"]), 8)
            self.assertLess(report["coupling_db"], -40.0)
            self.assertGreater(report["main_lobe_gain_db"], 10 * math.log10(8) - 3.0)
            # phase errors only make the null shallower, more so when larger
            e = report["expected_coupling_db"]
            self.assertLess(report["coupling_db"], e["1"])
            self.assertLess(e["1"], e["2"])
            self.assertLess(e["2"], e["5"])
            self.assertGreater(os.path.getsize(png), 10000)

    def test_bad_designs_get_one_clear_error(self):
        for args, words in ((("--main-lobe-deg", "10"), "inside the main lobe"),
                            (("--null-deg", "302"), "inside the main lobe"),
                            (("--null-deg", "10", "--null-deg", "40", "--null-deg", "60", "--null-deg", "80",
                              "--null-deg", "100", "--null-deg", "120", "--null-deg", "140"), "at most")):
            out = self.run_cli(*args)
            self.assertEqual(out.returncode, 2)
            self.assertIn(words, out.stderr)
            self.assertNotIn("Traceback", out.stderr)


if __name__ == "__main__":
    gr_unittest.main()
