#!/usr/bin/env python3
#
# SPDX-License-Identifier: GPL-3.0-or-later
#
"""QA of ofdm_sounder and ofdm_channel_estimator on synthetic multichannel streams."""

import time

import numpy as np
import pmt
from gnuradio import blocks, gr, gr_unittest

from gnuradio import thrumapper
from gnuradio.thrumapper.testing import free_finished_flowgraphs, wait_for




class SyntheticChannel:
    """RX element m receives Σ_k g[k, m]·x_k delayed by `delay` samples: CSI known exactly."""

    def __init__(self, sounding, delay=3, seed=1):
        rng = np.random.default_rng(seed)
        self.sounding = sounding
        self.delay = delay
        K, M = sounding.num_tx, sounding.num_rx
        self.gain = (rng.standard_normal((K, M)) + 1j * rng.standard_normal((K, M))) * 0.3

    def streams(self, frames, weights=()):
        x = np.tile(self.sounding.frame(list(weights)), (1, frames))  # (K, frames·P)
        y = np.einsum("km,kt->mt", self.gain, x)
        y = np.concatenate((np.zeros((y.shape[0], self.delay), complex), y[:, :-self.delay]), axis=1)
        return y.astype(np.complex64)

    def csi(self, weights):
        """(M, N) for the weighted mode."""
        s = self.sounding
        bins = np.asarray(s.subcarrier_signed_bins)
        ramp = np.exp(-2j * np.pi * bins * self.delay / s.fft_len)
        return np.einsum("k,km->m", np.asarray(weights), self.gain)[:, None] * ramp[None, :]

    def element_csi(self):
        """(K, M, N): every TX element alone, weight 1."""
        s = self.sounding
        bins = np.asarray(s.subcarrier_signed_bins)
        ramp = np.exp(-2j * np.pi * bins * self.delay / s.fft_len)
        return self.gain[:, :, None] * ramp[None, None, :]


def run_estimator(sounding, streams, tags=(), **kwargs):
    tb = gr.top_block()
    est = thrumapper.ofdm_channel_estimator(sounding, **kwargs)
    sink = blocks.vector_sink_c(sounding.num_rx * sounding.num_subcarriers)
    for m, stream in enumerate(streams):
        src = blocks.vector_source_c(stream.tolist(), False, 1, list(tags) if m == 0 else [])
        tb.connect(src, (est, m))
    tb.connect(est, sink)
    tb.run()
    csi = np.array(sink.data()).reshape(-1, sounding.num_rx, sounding.num_subcarriers)
    by_offset = {}
    for tag in sink.tags():
        by_offset.setdefault(tag.offset, {})[pmt.symbol_to_string(tag.key)] = tag.value
    return est, csi, by_offset


class qa_ofdm_channel_estimator(gr_unittest.TestCase):
    def tearDown(self):
        free_finished_flowgraphs()

    def setUp(self):
        self.radar = thrumapper.radar_description.make_uca_pair()
        self.sounding = thrumapper.ofdm_sounding.make(self.radar)
        self.weights = np.exp(1j * np.linspace(0, 2, 8)) * np.linspace(0.5, 1.0, 8)

    def test_csi_layout_tags_and_values(self):
        channel = SyntheticChannel(self.sounding)
        streams = channel.streams(6, self.weights)
        rx_time = pmt.make_tuple(pmt.from_uint64(1700000000), pmt.from_double(0.25))
        tags = [gr.tag_utils.python_to_tag((0, pmt.intern("rx_time"), rx_time)),
                gr.tag_utils.python_to_tag((10, pmt.intern("pose"), pmt.init_f64vector(3, [1.0, 2.0, 0.5])))]
        est, csi, by_offset = run_estimator(self.sounding, streams, tags)
        self.assertEqual(csi.shape[0], 6)
        expected = channel.csi(self.weights)
        P = self.sounding.frame_len
        for i in range(csi.shape[0]):
            np.testing.assert_allclose(csi[i], expected, atol=2e-5)
            t = by_offset[i]
            self.assertEqual(pmt.to_uint64(t["frame_index"]), i)
            self.assertEqual(pmt.to_long(t["timing_offset"]), channel.delay)
            self.assertGreater(pmt.to_double(t["preamble_metric"]), 0.9)
            secs = pmt.to_uint64(pmt.tuple_ref(t["rx_time"], 0))
            frac = pmt.to_double(pmt.tuple_ref(t["rx_time"], 1))
            self.assertAlmostEqual((secs - 1700000000) + frac, 0.25 + i * P / 120e6, places=12)
            np.testing.assert_allclose(pmt.f64vector_elements(t["pose"]), [1.0, 2.0, 0.5])
        self.assertEqual(est.num_frames(), 6)
        self.assertEqual(est.num_missing_preamble(), 0)

    def test_timing_acquired_from_the_first_preamble(self):
        channel = SyntheticChannel(self.sounding)
        rng = np.random.default_rng(8)
        junk = (1e-3 * (rng.standard_normal((8, 2777)) + 1j * rng.standard_normal((8, 2777)))).astype(np.complex64)
        streams = np.concatenate((junk, channel.streams(5, self.weights)), axis=1)
        est, csi, by_offset = run_estimator(self.sounding, streams, frame_offset=-1)
        self.assertEqual(csi.shape[0], 4)  # the fifth frame's search window runs past the end
        # the grid sits on the detected arrival: the CSI has no delay ramp left
        no_delay = SyntheticChannel(self.sounding, delay=0)
        for i in range(csi.shape[0]):
            self.assertEqual(pmt.to_uint64(by_offset[i]["frame_index"]), i)
            self.assertEqual(pmt.to_long(by_offset[i]["timing_offset"]), 0)
            np.testing.assert_allclose(csi[i], no_delay.csi(self.weights), atol=2e-5)
        with self.assertRaises(ValueError):
            thrumapper.ofdm_channel_estimator(self.sounding, -2)

    def test_missing_or_damaged_preamble_is_skipped_and_counted(self):
        channel = SyntheticChannel(self.sounding)
        streams = channel.streams(8, self.weights)
        P, Lp = self.sounding.frame_len, self.sounding.preamble_len
        start = 3 * P + channel.delay
        streams[:, start:start + Lp] = 0  # frame 3: preamble missing
        rng = np.random.default_rng(2)
        start = 5 * P + channel.delay
        noise = rng.standard_normal((streams.shape[0], Lp)) + 1j * rng.standard_normal((streams.shape[0], Lp))
        streams[:, start:start + Lp] = 0.5 * noise  # frame 5: preamble damaged
        est, csi, by_offset = run_estimator(self.sounding, streams)
        indices = [pmt.to_uint64(by_offset[i]["frame_index"]) for i in range(csi.shape[0])]
        self.assertEqual(indices, [0, 1, 2, 4, 6, 7])
        self.assertEqual(est.num_missing_preamble(), 2)
        for i in range(csi.shape[0]):
            np.testing.assert_allclose(csi[i], channel.csi(self.weights), atol=2e-5)

    def test_overflow_tags_keep_the_frames_in_step(self):
        channel = SyntheticChannel(self.sounding)
        streams = channel.streams(10, self.weights)
        P = self.sounding.frame_len
        fs = self.sounding.sample_rate_hz
        gap_from, gap_to = 4 * P + 700, 5 * P + 333  # an overflow drops these samples
        streams = np.concatenate((streams[:, :gap_from], streams[:, gap_to:]), axis=1)

        def rx_time(seconds):
            whole = int(seconds)
            return pmt.make_tuple(pmt.from_uint64(100 + whole), pmt.from_double(seconds - whole))

        tags = [gr.tag_utils.python_to_tag((0, pmt.intern("rx_time"), rx_time(0.0))),
                gr.tag_utils.python_to_tag((gap_from, pmt.intern("rx_time"), rx_time(gap_to / fs)))]
        est, csi, by_offset = run_estimator(self.sounding, streams, tags)
        indices = [pmt.to_uint64(by_offset[i]["frame_index"]) for i in range(csi.shape[0])]
        self.assertEqual(indices, [0, 1, 2, 3, 6, 7, 8, 9])  # 4 is cut, 5 lost in the gap
        self.assertEqual(est.num_discontinuities(), 1)
        self.assertEqual(est.num_discontinuity_skips(), 2)
        self.assertEqual(est.num_missing_preamble(), 0)
        for i in range(csi.shape[0]):
            np.testing.assert_allclose(csi[i], channel.csi(self.weights), atol=2e-5)
            self.assertEqual(pmt.to_long(by_offset[i]["timing_offset"]), channel.delay)
        t = by_offset[4]["rx_time"]
        self.assertAlmostEqual(pmt.to_uint64(pmt.tuple_ref(t, 0)) - 100 + pmt.to_double(pmt.tuple_ref(t, 1)),
                               6 * P / fs, places=12)

    def test_calibration_modes_give_every_element_alone(self):
        for mode in (thrumapper.sounding_mode.sequential, thrumapper.sounding_mode.interleaved):
            sounding = thrumapper.ofdm_sounding.make(self.radar, 120e6, 256, 64, 2, 128, 64, mode)
            channel = SyntheticChannel(sounding)
            est, csi, by_offset = run_estimator(sounding, channel.streams(3))
            truth = channel.element_csi()  # (K, M, N)
            K = sounding.num_tx
            if mode == thrumapper.sounding_mode.sequential:
                self.assertEqual(csi.shape[0], 3 * K)
                for i in range(csi.shape[0]):
                    k = pmt.to_long(by_offset[i]["tx_element"])
                    self.assertEqual(k, i % K)
                    np.testing.assert_allclose(csi[i], truth[k], atol=2e-5)
                    unit = pmt.c64vector_elements(by_offset[i]["tx_weights"])
                    self.assertEqual(unit, [1.0 if j == k else 0.0 for j in range(K)])
            else:
                self.assertEqual(csi.shape[0], 3)
                n = np.arange(sounding.num_subcarriers)
                for i in range(csi.shape[0]):
                    np.testing.assert_allclose(csi[i], truth[n % K, :, n].T, atol=2e-5)
                    self.assertEqual(pmt.symbol_to_string(by_offset[i]["sounding_mode"]), "interleaved")

    def test_sounder_weights_message_and_burst_tags(self):
        tb = gr.top_block()
        sounder = thrumapper.ofdm_sounder(self.sounding, list(self.weights), 10.5)
        K, P = self.sounding.num_tx, self.sounding.frame_len
        sinks = [blocks.vector_sink_c() for _ in range(K)]
        for k in range(K):
            # throttled, so that the flowgraph still runs when the message arrives
            tb.connect((sounder, k), blocks.throttle(gr.sizeof_gr_complex, 40 * P), blocks.head(gr.sizeof_gr_complex, 40 * P),
                       sinks[k])
        new = np.exp(-1j * np.arange(K))
        tb.start()
        try:
            self.assertTrue(wait_for(lambda: len(sinks[0].data()) > 0))
            sounder._post(pmt.intern("weights"), pmt.dict_add(pmt.make_dict(), pmt.intern("weights"),
                                                              pmt.init_c64vector(K, list(new))))
            sounder._post(pmt.intern("weights"), pmt.init_c32vector(3, [1, 2, 3]))  # wrong length
            sounder._post(pmt.intern("weights"), pmt.intern("nonsense"))
            self.assertTrue(wait_for(lambda: sounder.num_rejected_weights() == 2))
            self.assertTrue(wait_for(lambda: np.allclose(sounder.weights(), new)))
        finally:
            tb.wait()
        frames = self.sounding.frame([])  # unweighted (weights of the radar are ones)
        data = np.array([s.data() for s in sinks])
        tags = {}
        for tag in sinks[0].tags():
            tags.setdefault(pmt.symbol_to_string(tag.key), []).append((tag.offset, tag.value))
        self.assertEqual([o for o, _ in tags["tx_sob"]], [i * P for i in range(40)])
        self.assertEqual([o for o, _ in tags["tx_eob"]], [i * P + P - 1 for i in range(40)])
        times = [pmt.to_uint64(pmt.tuple_ref(v, 0)) + pmt.to_double(pmt.tuple_ref(v, 1)) for _, v in tags["tx_time"]]
        np.testing.assert_allclose(np.diff(times), P / 120e6, rtol=1e-9)
        self.assertAlmostEqual(times[0], 10.5)
        changes = [o for o, _ in tags["tx_weights"]]
        self.assertEqual(changes[0], 0)
        self.assertEqual(len(changes), 2)  # the initial weights and the new ones
        switch = changes[1]
        self.assertEqual(switch % P, 0)
        for k in range(K):
            np.testing.assert_allclose(data[k, :P], frames[k] * self.weights[k], atol=1e-6)
            np.testing.assert_allclose(data[k, switch:switch + P], frames[k] * new[k], atol=1e-6)

    def test_bad_construction_is_refused(self):
        with self.assertRaises(ValueError):
            thrumapper.ofdm_channel_estimator(self.sounding, 0, -1, -1, 1.5)
        with self.assertRaises(ValueError):
            thrumapper.ofdm_channel_estimator(self.sounding, 0, -1, 65)
        with self.assertRaises(ValueError):
            thrumapper.ofdm_sounder(self.sounding, [1, 2, 3])
        with self.assertRaises(ValueError):
            thrumapper.ofdm_sounding.make(self.radar, 122.88e6, 128)


if __name__ == "__main__":
    gr_unittest.run(qa_ofdm_channel_estimator)
