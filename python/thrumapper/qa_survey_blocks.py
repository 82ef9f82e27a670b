#!/usr/bin/env python3
#
# SPDX-License-Identifier: GPL-3.0-or-later
#
"""QA for survey_source and survey_sink: replay, recording, tags and pose messages."""

import gc
import os
import shutil
import tempfile
import time

import numpy as np
import pmt
from gnuradio import blocks, gr, gr_unittest

try:
    from gnuradio.thrumapper import survey, survey_blocks
except ImportError:  # the package is not built yet: use the files beside this one
    import sys

    sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
    import survey
    import survey_blocks

M, N, K = 3, 5, 2
FREQ_HZ = 2.44e9
TIMEOUT_S = 10.0


def wait_for(predicate, timeout_s=TIMEOUT_S):
    """Poll until predicate() holds; False on timeout."""
    deadline = time.monotonic() + timeout_s
    while not predicate():
        if time.monotonic() > deadline:
            return False
        time.sleep(0.005)
    return True


def tags_by_key(tags):
    found = {}
    for tag in tags:
        found.setdefault(pmt.symbol_to_string(tag.key), {})[tag.offset] = tag.value
    return found


class qa_survey_blocks(gr_unittest.TestCase):
    def setUp(self):
        self.tb = gr.top_block()
        self.dir = tempfile.mkdtemp(prefix="qa_survey_blocks_")
        rng = np.random.default_rng(3)
        self.frames = 6
        self.csi = (rng.standard_normal((self.frames, M, N)) + 1j * rng.standard_normal((self.frames, M, N))).astype(
            np.complex64
        )
        # Frames 0-1 at one pose, 2 a reference shot, 3-4 at a second pose, 5 at a third.
        self.poses = np.array(
            [[0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [np.nan] * 3, [0.5, 0.1, 0.2], [0.5, 0.1, 0.2], [1.0, 0.2, 0.4]]
        )
        self.types = ["survey", "survey", "rx_reference", "survey", "survey", "survey"]
        self.freqs_hz = FREQ_HZ + np.arange(self.frames) * 10.0
        self.stamps = [f"2024-05-06T07:08:{9 + f:02d}.250000000Z" for f in range(self.frames)]
        self.frame_w = np.ones((self.frames, K), dtype=np.complex128)
        self.frame_w[4] = [0.5j, -1.0]
        self.offsets_hz = np.linspace(-2e6, 2e6, N)
        self.rx_m = rng.uniform(-0.1, 0.1, (M, 2))
        self.tx_m = rng.uniform(-0.1, 0.1, (K, 2))
        self.meta = survey.write_survey(
            os.path.join(self.dir, "in"),
            self.csi,
            subcarrier_offsets_hz=self.offsets_hz,
            center_frequency_hz=self.freqs_hz,
            rx_elements_m=self.rx_m,
            tx_elements_m=self.tx_m,
            poses=self.poses,
            frame_types=self.types,
            frame_tx_weights=self.frame_w,
            datetimes=self.stamps,
        )

    def tearDown(self):
        self.tb = None
        gc.collect()  # the flowgraph's cycles freed here, not in a later test's block thread (qa_radio_chain)
        shutil.rmtree(self.dir, ignore_errors=True)

    def make_sink(self, name, **kwargs):
        return survey_blocks.survey_sink(
            os.path.join(self.dir, name), M, N, self.offsets_hz, FREQ_HZ, self.rx_m, self.tx_m, np.ones(K), **kwargs
        )

    def test_source_items_and_tags(self):
        src = survey_blocks.survey_source(self.meta)
        dst = blocks.vector_sink_c(M * N)
        self.tb.connect(src, dst)
        self.tb.run()
        played = np.array([0, 1, 3, 4, 5])  # survey frames only, by default
        items = np.array(dst.data(), dtype=np.complex64).reshape(-1, M * N)
        self.assertEqual(items.shape[0], played.size)
        # Element-major items: item[m*N + n] is csi[f, m, n].
        for i, f in enumerate(played):
            for m in range(M):
                for n in range(N):
                    self.assertEqual(items[i, m * N + n], self.csi[f, m, n])
        tags = tags_by_key(dst.tags())
        self.assertEqual({o: pmt.to_uint64(v) for o, v in tags["frame_index"].items()}, dict(enumerate(played)))
        for i, f in enumerate(played):
            self.assertFloatTuplesAlmostEqual(pmt.f64vector_elements(tags["pose"][i]), self.poses[f], 15)
            self.assertEqual(pmt.to_double(tags["rx_freq"][i]), self.freqs_hz[f])
            rx_time = tags["rx_time"][i]
            self.assertEqual(pmt.to_uint64(pmt.tuple_ref(rx_time, 0)), 1714979289 + f)
            self.assertEqual(pmt.to_double(pmt.tuple_ref(rx_time, 1)), 0.25)
            self.assertEqual(pmt.symbol_to_string(tags["frame_type"][i]), "survey")
        # Only frame 4 overrides the TX weights.
        self.assertEqual(list(tags["tx_weights"]), [3])
        self.assertEqual(list(pmt.c64vector_elements(tags["tx_weights"][3])), [0.5j, -1.0])

    def test_source_all_frame_types_and_repeat(self):
        src = survey_blocks.survey_source(self.meta, repeat=True, frame_types="all")
        head = blocks.head(gr.sizeof_gr_complex * M * N, 2 * self.frames + 1)
        dst = blocks.vector_sink_c(M * N)
        self.tb.connect(src, head, dst)
        self.tb.run()
        items = np.array(dst.data(), dtype=np.complex64).reshape(-1, M, N)
        expected = self.csi[np.r_[np.arange(self.frames), np.arange(self.frames), 0]]
        self.assertTrue(np.array_equal(items, expected))
        tags = tags_by_key(dst.tags())
        self.assertEqual(pmt.symbol_to_string(tags["frame_type"][2]), "rx_reference")
        self.assertNotIn(2, tags["pose"])  # a reference frame has no pose

        only_ref = survey_blocks.survey_source(self.meta, frame_types="rx_reference")
        self.assertEqual(only_ref.num_frames(), 1)
        with self.assertRaises(ValueError):
            survey_blocks.survey_source(self.meta, frame_types="calibration")
        # GRC states the vector length up front; a survey of another shape is refused.
        self.assertEqual(survey_blocks.survey_source(self.meta, num_rx=M, num_subcarriers=N).num_rx(), M)
        with self.assertRaises(ValueError):
            survey_blocks.survey_source(self.meta, num_rx=M, num_subcarriers=N + 1)

    def test_source_pose_messages(self):
        src = survey_blocks.survey_source(self.meta)
        dst = blocks.null_sink(gr.sizeof_gr_complex * M * N)
        debug = blocks.message_debug()
        self.tb.connect(src, dst)
        self.tb.msg_connect((src, "pose"), (debug, "store"))
        self.tb.start()
        # One message per change of pose: frames 0, 3 and 5.
        self.assertTrue(wait_for(lambda: debug.num_messages() >= 3))
        self.tb.stop()
        self.tb.wait()
        self.assertEqual(debug.num_messages(), 3)
        for i, f in enumerate([0, 3, 5]):
            msg = debug.get_message(i)
            self.assertTrue(pmt.is_dict(msg))
            self.assertEqual(pmt.to_long(pmt.dict_ref(msg, pmt.intern("frame_index"), pmt.PMT_NIL)), f)
            pose = pmt.f64vector_elements(pmt.dict_ref(msg, pmt.intern("pose"), pmt.PMT_NIL))
            self.assertFloatTuplesAlmostEqual(pose, self.poses[f], 15)
            for j, key in enumerate(("x", "y", "heading")):
                self.assertEqual(pmt.to_double(pmt.dict_ref(msg, pmt.intern(key), pmt.PMT_NIL)), self.poses[f][j])

    def test_round_trip_through_flowgraph(self):
        src = survey_blocks.survey_source(self.meta, frame_types="all")
        sink = self.make_sink("out")
        self.tb.connect(src, sink)
        self.tb.run()
        self.assertEqual(sink.frames_written(), self.frames)
        self.assertEqual(sink.skipped_frames(), 0)
        out = survey.read_survey(sink.meta_path())
        self.assertTrue(np.array_equal(out.csi, self.csi))
        self.assertTrue(np.array_equal(out.poses, self.poses, equal_nan=True))
        self.assertEqual(out.frame_types, self.types)
        self.assertEqual(out.datetimes, self.stamps)
        self.assertTrue(np.array_equal(out.center_frequencies_hz, self.freqs_hz))
        self.assertTrue(np.array_equal(out.frame_tx_weights, self.frame_w))
        self.assertTrue(np.array_equal(out.rx_elements_m, self.rx_m))
        self.assertTrue(np.array_equal(out.subcarrier_offsets_hz, self.offsets_hz))

    def test_sink_skips_nan_frames_and_frames_without_pose(self):
        frames = self.csi[[0, 1, 3, 4]].copy()
        frames[2, 1, 4] = complex(np.nan, 0.0)
        items = frames.reshape(-1)
        pose_tag = gr.tag_utils.python_to_tag(
            (1, pmt.intern("pose"), pmt.init_f64vector(3, [2.0, 3.0, 0.5]), pmt.intern("qa"))
        )
        # Frame 0 comes before any pose; frame 1 brings one; frame 2 holds a NaN.
        src = blocks.vector_source_c(items.tolist(), False, M * N, [pose_tag])
        sink = self.make_sink("skips")
        self.tb.connect(src, sink)
        self.tb.run()
        self.assertEqual(sink.skipped_frames(), 2)
        self.assertEqual(sink.skipped_nonfinite(), 1)
        self.assertEqual(sink.skipped_no_pose(), 1)
        out = survey.read_survey(sink.meta_path())
        self.assertTrue(np.array_equal(out.csi, frames[[1, 3]]))
        self.assertTrue(np.array_equal(out.poses, [[2.0, 3.0, 0.5]] * 2))
        self.assertTrue(np.array_equal(out.center_frequencies_hz, [FREQ_HZ] * 2))

    def test_sink_pose_from_message_and_incremental_writes(self):
        frame_bytes = M * N * 8
        src = blocks.vector_source_c(self.csi[0].reshape(-1).tolist(), True, M * N)
        throttle = blocks.throttle(gr.sizeof_gr_complex * M * N, 2000)
        sink = self.make_sink("live")
        self.tb.connect(src, throttle, sink)
        msg = pmt.make_dict()
        for key, value in (("x", 4.0), ("y", -1.0), ("heading", 3.0)):
            msg = pmt.dict_add(msg, pmt.intern(key), pmt.from_double(value))
        sink._post(pmt.intern("pose"), msg)
        self.tb.start()
        self.assertTrue(wait_for(lambda: sink.frames_written() >= 5))
        # The frames are on disk while the flowgraph runs; the metadata comes on stop().
        self.assertGreaterEqual(os.path.getsize(sink.data_path()), 5 * frame_bytes)
        self.assertFalse(os.path.exists(sink.meta_path()))
        self.tb.stop()
        self.tb.wait()
        out = survey.read_survey(sink.meta_path())
        self.assertEqual(out.num_frames, sink.frames_written())
        self.assertGreaterEqual(out.num_frames, 5)
        self.assertEqual(sink.skipped_frames(), 0)
        self.assertTrue(np.array_equal(out.csi, np.broadcast_to(self.csi[0], out.csi.shape)))
        self.assertTrue(np.array_equal(out.poses, np.tile([4.0, -1.0, 3.0], (out.num_frames, 1))))

    def test_sink_rejects_inconsistent_arguments(self):
        with self.assertRaises(ValueError):
            survey_blocks.survey_sink(os.path.join(self.dir, "x"), M + 1, N, self.offsets_hz, FREQ_HZ,
                                      self.rx_m, self.tx_m, np.ones(K))
        with self.assertRaises(ValueError):
            survey_blocks.survey_sink(os.path.join(self.dir, "x"), M, N, self.offsets_hz[::-1], FREQ_HZ,
                                      self.rx_m, self.tx_m, np.ones(K))


if __name__ == "__main__":
    gr_unittest.run(qa_survey_blocks)
