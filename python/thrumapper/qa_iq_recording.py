#!/usr/bin/env python3
#
# SPDX-License-Identifier: GPL-3.0-or-later
#
"""QA of the SigMF IQ recorder and replayer: a recorded survey replays to the same CSI."""

import json
import os
import tempfile

import numpy as np
import pmt
from gnuradio import blocks, gr, gr_unittest

from gnuradio import thrumapper
from gnuradio.thrumapper import building_sim, scene as scene_mod
from gnuradio.thrumapper.testing import free_finished_flowgraphs


def small_scene():
    return scene_mod.load_scene({
        "name": "iq", "seed": 3,
        "radar": {"elements": 8, "radius_m": 0.08, "baseline_m": 0.7, "carrier_hz": 2.44e9,
                  "bandwidth_hz": 120e6, "subcarriers": 128},
        "walls": [{"segment": [[-4.0, -0.775], [4.0, -0.775]], "material": "plasterboard"}],
        "trajectory": {"poses_deg": [[0.0, 0.0, 0.0]]},
        "impairments": {"system_delay_s": 12e-9, "rx": {"gain_db_std": 1, "phase_deg": "uniform", "delay_ps_std": 80}},
    })


def receive_chain(tb, sounding, sources, frame_offset=0):
    """M streams → calibrator → estimator → sink."""
    cal = thrumapper.channel_calibrator(sounding, "reference", 3 * sounding.frame_len, 0, True, "", frame_offset)
    est = thrumapper.ofdm_channel_estimator(sounding, frame_offset)
    sink = blocks.vector_sink_c(sounding.num_rx * sounding.num_subcarriers)
    for m, source in enumerate(sources):
        tb.connect(source, (cal, m), (est, m))
    tb.connect(est, sink)
    return sink


def frames_and_tags(sink, sounding):
    csi = np.array(sink.data()).reshape(-1, sounding.num_rx, sounding.num_subcarriers)
    tags = {}
    for tag in sink.tags():
        tags.setdefault(tag.offset, {})[pmt.symbol_to_string(tag.key)] = pmt.write_string(tag.value)
    return csi, tags


class qa_iq_recording(gr_unittest.TestCase):
    def tearDown(self):
        free_finished_flowgraphs()

    def test_recorded_survey_replays_to_the_same_csi(self):
        scene = small_scene()
        r = scene.radar
        radar = thrumapper.radar_description.make(r.tx_elements_m, r.rx_elements_m, r.carrier_hz,
                                                  list(r.subcarrier_offsets_hz))
        sounding = thrumapper.ofdm_sounding.make(radar)
        P, M = sounding.frame_len, sounding.num_rx
        with tempfile.TemporaryDirectory() as tmp:
            path = os.path.join(tmp, "survey_iq")
            tb = gr.top_block()
            sounder = thrumapper.ofdm_sounder(sounding, [], 1700000000.5)
            channel = thrumapper.building_channel(scene, sounding, reference_samples=4 * P)
            for k in range(sounding.num_tx):
                tb.connect((sounder, k), blocks.head(gr.sizeof_gr_complex, 10 * P), (channel, k))
            recorder = thrumapper.iq_sink(path, sounding, 0, "radio chain QA")
            for m in range(M):
                tb.connect((channel, m), (recorder, m))
            live = receive_chain(tb, sounding, [(channel, m) for m in range(M)])
            tb.run()
            live_csi, live_tags = frames_and_tags(live, sounding)
            self.assertGreaterEqual(live_csi.shape[0], 8)

            # the file: SigMF that SigMF's own tools accept, with the waveform described
            import sigmf
            meta = sigmf.sigmffile.fromfile(path + ".sigmf-meta")
            meta.validate()
            info = meta.get_global_info()
            self.assertEqual(info["thrumapper:kind"], "iq")
            self.assertEqual(info["core:num_channels"], M)
            self.assertEqual(info["core:sample_rate"], 120e6)
            self.assertEqual(info["thrumapper:sounding"]["frame_len"], P)
            self.assertEqual(info["thrumapper:sounding"]["subcarrier_bins"], list(range(-127, 128, 2)))
            captures = meta.get_captures()
            self.assertEqual(captures[0]["thrumapper:rx_time"], [1700000000, 0.5])
            self.assertEqual(captures[0]["core:frequency"], 2.44e9)
            kinds = [a.get("thrumapper:frame_type") for a in meta.get_annotations() if "thrumapper:frame_type" in a]
            self.assertEqual(kinds, ["rx_reference", "survey"])

            # replay: the same CSI, sample for sample, and the same tags
            source = thrumapper.iq_source(path)
            replayed = source.sounding()
            self.assertEqual(replayed.frame_len, P)
            self.assertEqual(list(replayed.subcarrier_bins), list(sounding.subcarrier_bins))
            self.assertEqual(source.num_samples(), recorder.samples_written())
            tb = gr.top_block()
            again = receive_chain(tb, replayed, [(source, m) for m in range(M)], source.frame_offset())
            tb.run()
            replay_csi, replay_tags = frames_and_tags(again, replayed)
            self.assertEqual(replay_csi.shape, live_csi.shape)
            # the same samples through the same code (FFTW may plan differently: float rounding)
            np.testing.assert_allclose(replay_csi, live_csi, rtol=0, atol=1e-5 * np.max(np.abs(live_csi)))
            for i in range(live_csi.shape[0]):
                for key in ("frame_index", "rx_time", "frame_type", "timing_offset", "pose"):
                    self.assertEqual(replay_tags[i].get(key), live_tags[i].get(key), key)

    def test_files_that_break_the_contract_are_refused(self):
        with tempfile.TemporaryDirectory() as tmp:
            path = os.path.join(tmp, "bad")
            sounding = thrumapper.ofdm_sounding.make(thrumapper.radar_description.make_uca_pair())
            tb = gr.top_block()
            sink = thrumapper.iq_sink(path, sounding)
            for m in range(sounding.num_rx):
                tb.connect(blocks.vector_source_c([0j] * 1000), (sink, m))
            tb.run()
            with open(path + ".sigmf-meta") as handle:
                meta = json.load(handle)
            meta["global"]["thrumapper:kind"] = "csi"
            with open(path + ".sigmf-meta", "w") as handle:
                json.dump(meta, handle)
            with self.assertRaises(thrumapper.SurveyFormatError) as err:
                thrumapper.iq_source(path)
            self.assertEqual(err.exception.field, "thrumapper:kind")
            meta["global"]["thrumapper:kind"] = "iq"
            del meta["global"]["thrumapper:sounding"]
            with open(path + ".sigmf-meta", "w") as handle:
                json.dump(meta, handle)
            with self.assertRaises(thrumapper.SurveyFormatError) as err:
                thrumapper.iq_source(path)
            self.assertEqual(err.exception.field, "thrumapper:sounding")


if __name__ == "__main__":
    gr_unittest.run(qa_iq_recording)
