#!/usr/bin/env python3
#
# SPDX-License-Identifier: GPL-3.0-or-later
#
"""QA for the survey format (FORMATS.md): reading, writing, and every rejection rule."""

import json
import os
import shutil
import tempfile

import numpy as np
import sigmf
from gnuradio import gr, gr_unittest  # noqa: F401  (gr_unittest runs the tests)

try:
    from gnuradio.thrumapper import survey
except ImportError:  # the package is not built yet: use the file beside this one
    import sys

    sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
    import survey

SurveyFormatError = survey.SurveyFormatError

M, N, K = 4, 6, 3  # small arrays: the rules do not depend on size
FREQ_HZ = 2.44e9


def random_csi(rng, frames):
    return (rng.standard_normal((frames, M, N)) + 1j * rng.standard_normal((frames, M, N))).astype(np.complex64)


class qa_survey(gr_unittest.TestCase):
    def setUp(self):
        self.dir = tempfile.mkdtemp(prefix="qa_survey_")
        self.rng = np.random.default_rng(7)
        self.offsets_hz = (np.arange(N) - N / 2) * 1.25e6
        self.rx_m = self.rng.uniform(-0.1, 0.1, (M, 2))
        self.tx_m = self.rng.uniform(-0.1, 0.1, (K, 2)) - [0.35, 0.0]
        self.weights = np.exp(1j * self.rng.uniform(-np.pi, np.pi, K))

    def tearDown(self):
        shutil.rmtree(self.dir, ignore_errors=True)

    # -- helpers ------------------------------------------------------------------------
    def write_valid(self, name="s", frames=4, **kwargs):
        """A valid survey of `frames` frames; returns (meta path, csi, poses)."""
        csi = random_csi(self.rng, frames)
        poses = np.column_stack([np.arange(frames) * 0.5, np.zeros(frames), np.full(frames, 0.25)])
        args = dict(
            subcarrier_offsets_hz=self.offsets_hz,
            center_frequency_hz=FREQ_HZ,
            rx_elements_m=self.rx_m,
            tx_elements_m=self.tx_m,
            tx_weights=self.weights,
            poses=poses,
        )
        args.update(kwargs)
        meta = survey.write_survey(os.path.join(self.dir, name), csi, **args)
        return meta, csi, poses

    def load(self, meta):
        with open(meta) as handle:
            return json.load(handle)

    def save(self, meta, metadata):
        # Python's json writes NaN/Infinity tokens, which lets the tests plant them.
        with open(meta, "w") as handle:
            json.dump(metadata, handle)

    def assert_rejected(self, meta, field, *fragments, validate_values=True):
        with self.assertRaises(SurveyFormatError) as ctx:
            survey.read_survey(meta, validate_values=validate_values)
        err = ctx.exception
        self.assertEqual(err.field, field, str(err))
        self.assertTrue(str(err).startswith(field) or field in str(err), str(err))
        for fragment in fragments:
            self.assertIn(fragment, str(err))
        return err

    def mutate(self, change, field, *fragments):
        """Write a valid survey, apply change(metadata) to its JSON, expect rejection."""
        meta, _, _ = self.write_valid()
        metadata = self.load(meta)
        change(metadata)
        self.save(meta, metadata)
        return self.assert_rejected(meta, field, *fragments)

    # -- round trip and layout ----------------------------------------------------------
    def test_round_trip_bit_exact(self):
        frames = 7
        csi = random_csi(self.rng, frames)
        poses = self.rng.uniform(-5, 5, (frames, 3))
        poses[3] = np.nan
        types = ["survey"] * frames
        types[3] = "rx_reference"
        frame_w = np.tile(self.weights, (frames, 1))
        frame_w[5] = [1 + 0j, -1j, 0.5 + 0.25j]
        freqs_hz = FREQ_HZ + np.arange(frames) * 1e3
        stamps = [None] * frames
        stamps[0] = "2025-03-04T05:06:07.123456789Z"
        meta = survey.write_survey(
            os.path.join(self.dir, "rt"),
            csi,
            subcarrier_offsets_hz=self.offsets_hz,
            center_frequency_hz=freqs_hz,
            rx_elements_m=self.rx_m,
            tx_elements_m=self.tx_m,
            tx_weights=self.weights,
            poses=poses,
            frame_types=types,
            frame_tx_weights=frame_w,
            system_delay_s=12.5e-9,
            wall_model={"relative_permittivity": 2.7, "thickness_m": 0.15},
            datetimes=stamps,
            description="round trip",
            author="qa",
            extra_global={"thrumapper:scene": "corridor"},
        )
        self.assertEqual(meta, os.path.join(self.dir, "rt.sigmf-meta"))
        s = survey.read_survey(meta)
        self.assertEqual((s.num_frames, s.num_rx, s.num_subcarriers, s.num_tx), (frames, M, N, K))
        self.assertEqual(s.csi.dtype, np.complex64)
        self.assertTrue(np.array_equal(s.csi, csi))
        self.assertTrue(np.array_equal(s.poses, poses, equal_nan=True))
        self.assertTrue(np.array_equal(s.subcarrier_offsets_hz, self.offsets_hz))
        self.assertTrue(np.array_equal(s.center_frequencies_hz, freqs_hz))
        self.assertTrue(np.array_equal(s.rx_elements_m, self.rx_m))
        self.assertTrue(np.array_equal(s.tx_elements_m, self.tx_m))
        self.assertTrue(np.array_equal(s.tx_weights, self.weights))
        self.assertTrue(np.array_equal(s.frame_tx_weights, frame_w))
        self.assertEqual(s.frame_types, types)
        self.assertEqual(s.datetimes, stamps)
        self.assertEqual(s.system_delay_s, 12.5e-9)
        self.assertEqual(s.wall_model, {"relative_permittivity": 2.7, "thickness_m": 0.15})
        self.assertEqual(s.global_info["thrumapper:scene"], "corridor")
        self.assertEqual(s.global_info["core:author"], "qa")
        self.assertTrue(np.array_equal(s.survey_frames(), [0, 1, 2, 4, 5, 6]))
        self.assertTrue(np.array_equal(s.reference_frames(), [3]))

        # Only the frame that overrides the weights carries them; the extension is declared.
        metadata = self.load(meta)
        self.assertEqual([i for i, c in enumerate(metadata["captures"]) if "thrumapper:tx_weights" in c], [5])
        self.assertIn({"name": "thrumapper", "version": "1.0.0", "optional": False},
                      metadata["global"]["core:extensions"])
        self.assertEqual([c["core:sample_start"] for c in metadata["captures"]], [f * N for f in range(frames)])
        self.assertNotIn("thrumapper:pose", metadata["captures"][3])

        # SigMF's own reader and validator accept it, checksum included.
        handle = sigmf.sigmffile.fromfile(meta)
        handle.validate()
        self.assertEqual(handle.get_global_field("core:num_channels"), M)

    def test_file_layout_from_another_tool(self):
        # A file written without write_survey, element (f*N + n)*M + m as FORMATS.md says,
        # with only the required fields: the reader must put it at csi[f, m, n].
        frames = 3
        f, n, m = np.meshgrid(np.arange(frames), np.arange(N), np.arange(M), indexing="ij")
        values = (f * 100 + n * 10 + m + 1j * (f + 2 * n + 3 * m)).astype("<c8")
        base = os.path.join(self.dir, "other")
        values.reshape(-1).tofile(base + ".sigmf-data")
        metadata = {
            "global": {
                "core:datatype": "cf32_le",
                "core:version": "1.0.0",
                "core:num_channels": M,
                "core:extensions": [{"name": "thrumapper", "version": "1.0.0", "optional": False}],
                "thrumapper:kind": "csi",
                "thrumapper:subcarrier_offsets_hz": list(self.offsets_hz),
                "thrumapper:rx_elements": self.rx_m.tolist(),
                "thrumapper:tx_elements": self.tx_m.tolist(),
                "thrumapper:tx_weights": [[1, 0]] * K,
                "other:thing": 3,
            },
            "captures": [
                {"core:sample_start": i * N, "core:frequency": FREQ_HZ, "thrumapper:pose": [i, 0, 0]}
                for i in range(frames)
            ],
            "annotations": [],
        }
        self.save(base + ".sigmf-meta", metadata)
        s = survey.read_survey(base)
        fi, mi, ni = 2, 3, 5
        self.assertEqual(s.csi[fi, mi, ni], np.complex64(fi * 100 + ni * 10 + mi + 1j * (fi + 2 * ni + 3 * mi)))
        expected = (f * 100 + n * 10 + m + 1j * (f + 2 * n + 3 * m)).transpose(0, 2, 1)
        self.assertTrue(np.array_equal(s.csi, expected.astype(np.complex64)))
        self.assertEqual(s.frame_types, ["survey"] * frames)
        self.assertEqual(s.datetimes, [None] * frames)
        self.assertIsNone(s.system_delay_s)
        self.assertIsNone(s.wall_model)
        self.assertTrue(np.array_equal(s.tx_weights, np.ones(K)))
        self.assertTrue(np.array_equal(s.poses[:, 0], np.arange(frames)))

    def test_csi_is_memory_mapped_read_only(self):
        meta, csi, _ = self.write_valid(frames=5)
        s = survey.read_survey(meta)
        self.assertIsInstance(s.csi, np.memmap)
        self.assertFalse(s.csi.flags.owndata)
        self.assertFalse(s.csi.flags.writeable)
        self.assertEqual(s.csi.shape, (5, M, N))
        with self.assertRaises(ValueError):
            s.csi[0, 0, 0] = 1

    def test_path_forms(self):
        meta, csi, _ = self.write_valid(name="forms")
        base = meta[: -len(".sigmf-meta")]
        for path in (base, base + ".sigmf-meta", base + ".sigmf-data"):
            s = survey.read_survey(path)
            self.assertEqual(s.meta_path, meta)
            self.assertEqual(s.data_path, base + ".sigmf-data")
            self.assertTrue(np.array_equal(s.csi, csi))

    def test_group_frames_by_pose(self):
        frames = 8
        poses = np.array(
            [[0, 0, 0], [0, 0, 0], [np.nan] * 3, [0, 0, 0], [1, 0, 0], [1, 0, 0], [1, 0, 0.5], [0, 0, 0]], float
        )
        types = ["survey", "survey", "rx_reference", "survey", "survey", "survey", "survey", "survey"]
        meta, _, _ = self.write_valid(frames=frames, poses=poses, frame_types=types)
        groups = survey.group_frames_by_pose(survey.read_survey(meta))
        self.assertEqual([g[0].tolist() for g in groups], [[0, 1, 3], [4, 5], [6], [7]])
        self.assertTrue(np.array_equal(groups[2][1], [1, 0, 0.5]))
        self.assertTrue(np.array_equal(groups[3][1], [0, 0, 0]))

    def test_empty_survey(self):
        meta = survey.write_survey(
            os.path.join(self.dir, "empty"),
            np.zeros((0, M, N), np.complex64),
            subcarrier_offsets_hz=self.offsets_hz,
            center_frequency_hz=FREQ_HZ,
            rx_elements_m=self.rx_m,
            tx_elements_m=self.tx_m,
        )
        s = survey.read_survey(meta)
        self.assertEqual(s.csi.shape, (0, M, N))
        self.assertEqual(survey.group_frames_by_pose(s), [])

    def test_datetime_conversion(self):
        self.assertEqual(survey.datetime_to_rx_time("1970-01-01T00:00:01.5Z"), (1, 0.5))
        self.assertEqual(survey.datetime_to_rx_time("2000-01-01T01:00:00+01:00"), (946684800, 0.0))
        self.assertEqual(survey.rx_time_to_datetime(946684800, 0.25), "2000-01-01T00:00:00.250000000Z")
        self.assertEqual(survey.rx_time_to_datetime(0, 0.9999999999), "1970-01-01T00:00:01.000000000Z")
        for bad in ("2000-02-30T00:00:00Z", "yesterday", "2000-01-01"):
            with self.assertRaises(ValueError):
                survey.datetime_to_rx_time(bad)

    # -- rejected surveys: each names its field ------------------------------------------
    def test_reject_malformed_json(self):
        meta, _, _ = self.write_valid()
        with open(meta, "w") as handle:
            handle.write('{"global": {"core:datatype": "cf32_le",')
        self.assert_rejected(meta, "sigmf-meta", meta, "malformed JSON")

    def test_reject_missing_meta_file(self):
        self.assert_rejected(os.path.join(self.dir, "nothing"), "sigmf-meta", "does not exist")

    def test_reject_missing_datatype(self):
        self.mutate(lambda md: md["global"].pop("core:datatype"), "core:datatype", "missing")

    def test_reject_wrong_datatype(self):
        self.mutate(lambda md: md["global"].update({"core:datatype": "ci16_le"}), "core:datatype", "ci16_le")

    def test_reject_missing_num_channels(self):
        self.mutate(lambda md: md["global"].pop("core:num_channels"), "core:num_channels")

    def test_reject_missing_kind(self):
        self.mutate(lambda md: md["global"].pop("thrumapper:kind"), "thrumapper:kind", "missing")

    def test_reject_unknown_kind(self):
        self.mutate(lambda md: md["global"].update({"thrumapper:kind": "iq"}), "thrumapper:kind", "'iq'")

    def test_reject_undeclared_extension(self):
        self.mutate(lambda md: md["global"].update({"core:extensions": []}), "core:extensions", "thrumapper")

    def test_reject_optional_extension(self):
        ext = [{"name": "thrumapper", "version": "1.0.0", "optional": True}]
        self.mutate(lambda md: md["global"].update({"core:extensions": ext}), "core:extensions", "optional")

    def test_reject_extension_major_version(self):
        ext = [{"name": "thrumapper", "version": "2.0.0", "optional": False}]
        self.mutate(lambda md: md["global"].update({"core:extensions": ext}), "core:extensions", "2.0.0")

    def test_reject_missing_tx_weights(self):
        self.mutate(lambda md: md["global"].pop("thrumapper:tx_weights"), "thrumapper:tx_weights", "missing")

    def test_reject_offsets_not_ascending(self):
        def change(md):
            offsets = md["global"]["thrumapper:subcarrier_offsets_hz"]
            offsets[2], offsets[3] = offsets[3], offsets[2]

        self.mutate(change, "thrumapper:subcarrier_offsets_hz", "ascending", "entry 3")

    def test_reject_offsets_not_finite(self):
        self.mutate(
            lambda md: md["global"]["thrumapper:subcarrier_offsets_hz"].__setitem__(1, float("nan")),
            "thrumapper:subcarrier_offsets_hz",
            "entry 1",
        )

    def test_reject_rx_element_count(self):
        err = self.mutate(
            lambda md: md["global"]["thrumapper:rx_elements"].pop(), "thrumapper:rx_elements"
        )
        self.assertIn(f"thrumapper:rx_elements: expected M={M} pairs [x, y], got {M - 1}", str(err))

    def test_reject_malformed_pair(self):
        self.mutate(
            lambda md: md["global"]["thrumapper:tx_elements"].__setitem__(1, [0.1, 0.2, 0.3]),
            "thrumapper:tx_elements",
            "entry 1",
        )

    def test_reject_tx_weight_count(self):
        err = self.mutate(lambda md: md["global"]["thrumapper:tx_weights"].pop(), "thrumapper:tx_weights")
        self.assertIn(f"expected K={K} pairs [re, im], got {K - 1}", str(err))

    def test_reject_missing_sample_start(self):
        self.mutate(lambda md: md["captures"][2].pop("core:sample_start"), "core:sample_start", "captures[2]")

    def test_reject_sample_start_not_f_times_n(self):
        self.mutate(lambda md: md["captures"][1].update({"core:sample_start": N + 1}), "core:sample_start",
                    f"{N}")

    def test_reject_captures_out_of_order(self):
        def change(md):
            md["captures"][1], md["captures"][2] = md["captures"][2], md["captures"][1]

        self.mutate(change, "core:sample_start", "captures[1]")

    def test_reject_missing_frequency(self):
        self.mutate(lambda md: md["captures"][3].pop("core:frequency"), "core:frequency", "captures[3]")

    def test_reject_survey_frame_without_pose(self):
        self.mutate(lambda md: md["captures"][0].pop("thrumapper:pose"), "thrumapper:pose", "captures[0]")

    def test_reject_pose_wrong_length(self):
        self.mutate(lambda md: md["captures"][1].update({"thrumapper:pose": [1.0, 2.0]}), "thrumapper:pose")

    def test_reject_pose_not_finite(self):
        self.mutate(
            lambda md: md["captures"][2].update({"thrumapper:pose": [1.0, float("inf"), 0.0]}), "thrumapper:pose"
        )

    def test_reject_unknown_frame_type(self):
        self.mutate(
            lambda md: md["captures"][1].update({"thrumapper:frame_type": "tx_reference"}),
            "thrumapper:frame_type",
            "tx_reference",
        )

    def test_reject_capture_tx_weights_length(self):
        self.mutate(
            lambda md: md["captures"][1].update({"thrumapper:tx_weights": [[1, 0]] * (K + 1)}),
            "thrumapper:tx_weights",
            "captures[1]",
        )

    def test_reject_wall_model(self):
        self.mutate(
            lambda md: md["global"].update({"thrumapper:wall_model": {"relative_permittivity": 2.7}}),
            "thrumapper:wall_model",
            "thickness_m",
        )

    def test_reject_system_delay(self):
        self.mutate(
            lambda md: md["global"].update({"thrumapper:system_delay_s": "10 ns"}), "thrumapper:system_delay_s"
        )

    def test_reject_bad_datetime(self):
        self.mutate(lambda md: md["captures"][0].update({"core:datetime": "noon"}), "core:datetime")

    def test_reject_by_sigmf_schema(self):
        # Nothing of ours; SigMF's schema wants a positive sample rate.
        self.mutate(lambda md: md["global"].update({"core:sample_rate": -1.0}), "core:sample_rate", "SigMF")

    def test_reject_missing_data_file(self):
        meta, _, _ = self.write_valid()
        os.remove(meta.replace(".sigmf-meta", ".sigmf-data"))
        self.assert_rejected(meta, "sigmf-data", "missing")

    def test_reject_partial_frame(self):
        meta, _, _ = self.write_valid()
        with open(meta.replace(".sigmf-meta", ".sigmf-data"), "ab") as handle:
            handle.write(b"\0" * 8)
        self.assert_rejected(meta, "sigmf-data", "not a whole number of frames")

    def test_reject_truncated_data(self):
        meta, _, _ = self.write_valid(frames=4)
        data = meta.replace(".sigmf-meta", ".sigmf-data")
        with open(data, "r+b") as handle:
            handle.truncate(3 * M * N * 8)
        self.assert_rejected(meta, "sigmf-data", "truncated", "3 frames", "4")

    def test_reject_nan_csi_with_frame_index(self):
        meta, csi, _ = self.write_valid(frames=5)
        data = meta.replace(".sigmf-meta", ".sigmf-data")
        values = np.fromfile(data, dtype="<c8")
        values[(3 * N + 2) * M + 1] = complex(np.nan, 0)  # frame 3
        values.tofile(data)
        metadata = self.load(meta)
        metadata["global"].pop("core:sha512")  # the hash would catch it first
        self.save(meta, metadata)
        self.assert_rejected(meta, "sigmf-data", "frame 3")
        # Not scanned on request: the file then opens.
        s = survey.read_survey(meta, validate_values=False)
        self.assertTrue(np.isnan(s.csi[3, 1, 2]))

    def test_reject_checksum_mismatch(self):
        meta, _, _ = self.write_valid()
        data = meta.replace(".sigmf-meta", ".sigmf-data")
        values = np.fromfile(data, dtype="<c8")
        values[5] += 1
        values.tofile(data)
        self.assert_rejected(meta, "core:sha512")

    # -- write_survey checks its own inputs ----------------------------------------------
    def test_write_rejects_bad_inputs(self):
        csi = random_csi(self.rng, 2)
        good = dict(
            subcarrier_offsets_hz=self.offsets_hz,
            center_frequency_hz=FREQ_HZ,
            rx_elements_m=self.rx_m,
            tx_elements_m=self.tx_m,
            poses=np.zeros((2, 3)),
        )
        path = os.path.join(self.dir, "bad")
        cases = [
            ("csi", dict(csi=csi[0])),
            ("csi: frame 1", dict(csi=np.where(np.arange(2)[:, None, None] == 1, np.nan, csi))),
            ("subcarrier_offsets_hz", dict(subcarrier_offsets_hz=self.offsets_hz[::-1])),
            ("subcarrier_offsets_hz", dict(subcarrier_offsets_hz=self.offsets_hz[:-1])),
            ("rx_elements_m", dict(rx_elements_m=self.rx_m[:-1])),
            ("tx_weights", dict(tx_weights=np.ones(K + 1))),
            ("poses: survey frame 0", dict(poses=np.full((2, 3), np.nan))),
            ("poses: row 1", dict(poses=np.array([[0, 0, 0], [0, np.nan, 0]]))),
            ("frame_types", dict(frame_types=["survey", "calibration"])),
            ("center_frequency_hz", dict(center_frequency_hz=[FREQ_HZ, np.inf])),
            ("wall_model", dict(wall_model={"relative_permittivity": 0.5, "thickness_m": 0.1})),
            ("system_delay_s", dict(system_delay_s=float("nan"))),
            ("datetimes[1]", dict(datetimes=[None, "later"])),
            ("extra_global", dict(extra_global={"core:datatype": "ci16_le"})),
        ]
        for fragment, change in cases:
            args = dict(good, csi=csi)
            args.update(change)
            data = args.pop("csi")
            with self.assertRaises(ValueError, msg=fragment) as ctx:
                survey.write_survey(path, data, **args)
            self.assertIn(fragment, str(ctx.exception))
            self.assertFalse(os.path.exists(path + ".sigmf-meta"), fragment)


if __name__ == "__main__":
    gr_unittest.run(qa_survey)
