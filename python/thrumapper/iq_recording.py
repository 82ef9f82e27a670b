#
# SPDX-License-Identifier: GPL-3.0-or-later
#
"""Raw IQ recordings of the M RX channels: SigMF with thrumapper:kind = "iq".

The global object describes the radar and the sounding waveform, so that a recording replays
through the receive chain (calibrator, channel estimator) with no other input; the fields
are documented in docs/radio-chain.md. Data: cf32_le, SigMF channel interleaving: the
value of sample t, channel m is element t·M + m.
"""

import hashlib
import json
import os
import threading

import numpy as np
import pmt
from gnuradio import gr
from sigmf import SigMFFile
from sigmf.sigmffile import get_sigmf_filenames

from .survey import EXTENSION_NAME, EXTENSION_VERSION, FILE_DTYPE, SurveyFormatError, _sigmf_validate
from .survey_blocks import pose_from_pmt

KIND = "iq"
DATATYPE = "cf32_le"
KEY_RX_TIME = pmt.intern("rx_time")
KEY_RX_FREQ = pmt.intern("rx_freq")
KEY_POSE = pmt.intern("pose")
KEY_FRAME_TYPE = pmt.intern("frame_type")
_MODES = {"weighted": 0, "sequential": 1, "interleaved": 2}
_WORK_DONE = int(gr.WORK_DONE)


def _mode_name(mode):
    return str(mode).split(".")[-1]


def sounding_metadata(sounding, frame_offset=0):
    """The global fields that describe the radar and the sounding waveform."""
    radar = sounding.radar
    weights = [[float(w.real), float(w.imag)] for w in radar.tx_weights]
    return {
        "core:sample_rate": float(sounding.sample_rate_hz),
        "thrumapper:kind": KIND,
        "thrumapper:subcarrier_offsets_hz": [float(v) for v in radar.subcarrier_offsets_hz],
        "thrumapper:rx_elements": [[float(x), float(y)] for x, y in np.asarray(radar.rx_elements_m)],
        "thrumapper:tx_elements": [[float(x), float(y)] for x, y in np.asarray(radar.tx_elements_m)],
        "thrumapper:tx_weights": weights,
        "thrumapper:carrier_hz": float(radar.carrier_hz),
        "thrumapper:sounding": {
            "fft_len": int(sounding.fft_len),
            "cp_len": int(sounding.cp_len),
            "num_symbols": int(sounding.num_symbols),
            "preamble_len": int(sounding.preamble_len),
            "gap_len": int(sounding.gap_len),
            "mode": _mode_name(sounding.mode),
            "tuning_offset_hz": float(sounding.tuning_offset_hz),
            "frame_len": int(sounding.frame_len),
            "subcarrier_bins": [int(b) for b in sounding.subcarrier_signed_bins],
        },
        "thrumapper:frame_offset": int(frame_offset),
    }


def sounding_from_metadata(global_info, path="?"):
    """(ofdm_sounding, frame_offset) rebuilt from an IQ recording's global object."""
    from . import thrumapper_python as _core

    def need(key):
        if key not in global_info:
            raise SurveyFormatError(key, "missing", path=path)
        return global_info[key]

    try:
        tx = np.asarray(need("thrumapper:tx_elements"), dtype=float).reshape(-1, 2)
        rx = np.asarray(need("thrumapper:rx_elements"), dtype=float).reshape(-1, 2)
        offsets = [float(v) for v in need("thrumapper:subcarrier_offsets_hz")]
        weights = [complex(re, im) for re, im in need("thrumapper:tx_weights")]
        carrier = float(need("thrumapper:carrier_hz"))
        spec = need("thrumapper:sounding")
        radar = _core.radar_description.make(tx, rx, carrier, offsets, weights)
        mode = getattr(_core.sounding_mode, spec["mode"])
        sounding = _core.ofdm_sounding.make(
            radar, float(need("core:sample_rate")), int(spec["fft_len"]), int(spec["cp_len"]),
            int(spec["num_symbols"]), int(spec["preamble_len"]), int(spec["gap_len"]), mode,
            float(spec["tuning_offset_hz"]))
    except SurveyFormatError:
        raise
    except (KeyError, TypeError, ValueError, AttributeError) as err:
        raise SurveyFormatError("thrumapper:sounding", str(err), path=path) from None
    if sounding.frame_len != int(spec.get("frame_len", sounding.frame_len)):
        raise SurveyFormatError("thrumapper:sounding",
                                f"frame_len says {spec['frame_len']} but the waveform has {sounding.frame_len}",
                                path=path)
    return sounding, int(global_info.get("thrumapper:frame_offset", 0))


class iq_sink(gr.sync_block):
    """Records the M RX channels as a SigMF IQ recording (thrumapper:kind "iq").

    Inputs: M complex streams (the radios, before calibration). The global object holds the
    radar and the sounding waveform (sounding_metadata); captures start at sample 0 and at
    every rx_time or rx_freq tag on input 0 (core:frequency, core:datetime and
    thrumapper:rx_time [seconds, fraction]); "pose" and "frame_type" tags on input 0 become
    annotations (thrumapper:pose, thrumapper:frame_type). Data are appended as they arrive;
    the metadata is written on stop().
    """

    def __init__(self, path, sounding, frame_offset=0, description=None):
        self._sounding = sounding
        self._M = int(sounding.num_rx)
        names = get_sigmf_filenames(os.fspath(path))
        self._meta_path, self._data_path = str(names["meta_fn"]), str(names["data_fn"])
        self._global = sounding_metadata(sounding, frame_offset)
        if description is not None:
            self._global["core:description"] = str(description)
        gr.sync_block.__init__(self, name="iq_sink", in_sig=[np.complex64] * self._M, out_sig=None)
        self._lock = threading.Lock()
        self._handle = None
        self._reset()

    def _reset(self):
        self._captures = []
        self._annotations = []
        self._frequency_hz = float(self._sounding.lo_frequency_hz)
        self._hasher = hashlib.sha512()
        self._samples = 0

    def meta_path(self):
        return self._meta_path

    def samples_written(self):
        with self._lock:
            return self._samples

    def start(self):
        with self._lock:
            self._reset()
            self._captures.append({"core:sample_start": 0, "core:frequency": self._frequency_hz})
            self._handle = open(self._data_path, "wb")
        return True

    def stop(self):
        with self._lock:
            if self._handle is None:
                return True
            self._handle.close()
            self._handle = None
            info = dict(self._global)
            info.update({
                "core:datatype": DATATYPE,
                "core:num_channels": self._M,
                "core:extensions": [{"name": EXTENSION_NAME, "version": EXTENSION_VERSION, "optional": False}],
                "core:recorder": "gr-thrumapper",
                "core:sha512": self._hasher.hexdigest(),
            })
            meta = SigMFFile(metadata={"global": info, "captures": self._captures,
                                       "annotations": self._annotations})
            meta.tofile(self._meta_path, overwrite=True)
        return True

    def _capture_at(self, offset):
        if self._captures and self._captures[-1]["core:sample_start"] == offset:
            return self._captures[-1]
        capture = {"core:sample_start": int(offset), "core:frequency": self._frequency_hz}
        self._captures.append(capture)
        return capture

    def work(self, input_items, output_items):
        count = min(len(x) for x in input_items)
        first = self.nitems_read(0)
        with self._lock:
            if self._handle is None:
                return count
            for tag in sorted(self.get_tags_in_window(0, 0, count), key=lambda t: t.offset):
                if pmt.eqv(tag.key, KEY_RX_FREQ) and pmt.is_number(tag.value):
                    self._frequency_hz = pmt.to_double(tag.value)
                    self._capture_at(tag.offset)["core:frequency"] = self._frequency_hz
                elif pmt.eqv(tag.key, KEY_RX_TIME) and pmt.is_tuple(tag.value) and pmt.length(tag.value) == 2:
                    secs = pmt.tuple_ref(tag.value, 0)
                    secs = pmt.to_uint64(secs) if pmt.is_uint64(secs) else pmt.to_long(secs)
                    frac = pmt.to_double(pmt.tuple_ref(tag.value, 1))
                    self._capture_at(tag.offset)["thrumapper:rx_time"] = [int(secs), float(frac)]
                elif pmt.eqv(tag.key, KEY_POSE):
                    pose = pose_from_pmt(tag.value)
                    if pose is not None:
                        self._annotations.append({"core:sample_start": int(tag.offset), "core:sample_count": 1,
                                                  "thrumapper:pose": [float(v) for v in pose]})
                elif pmt.eqv(tag.key, KEY_FRAME_TYPE) and pmt.is_symbol(tag.value):
                    self._annotations.append({"core:sample_start": int(tag.offset), "core:sample_count": 1,
                                              "thrumapper:frame_type": pmt.symbol_to_string(tag.value)})
            data = np.empty((count, self._M), dtype=FILE_DTYPE)
            for m in range(self._M):
                data[:, m] = input_items[m][:count]
            raw = memoryview(data).cast("B")
            self._hasher.update(raw)
            self._handle.write(raw)
            self._samples = first + count
        return count


class iq_source(gr.sync_block):
    """Replays a SigMF IQ recording (thrumapper:kind "iq") as M complex streams.

    Tags on output 0 (and every output): "rx_freq" and "rx_time" at each capture's start,
    "pose" and "frame_type" from the annotations, so the receive chain sees what the radios
    gave. sounding() rebuilds the ofdm_sounding from the metadata, frame_offset() the grid.
    """

    def __init__(self, path, repeat=False):
        names = get_sigmf_filenames(os.fspath(path))
        self._meta_path, self._data_path = str(names["meta_fn"]), str(names["data_fn"])
        try:
            with open(self._meta_path) as handle:
                meta = json.load(handle)
        except OSError as err:
            raise SurveyFormatError("sigmf-meta", f"cannot read: {err}", path=self._meta_path) from None
        except ValueError as err:
            raise SurveyFormatError("sigmf-meta", f"not JSON: {err}", path=self._meta_path) from None
        _sigmf_validate(meta, self._meta_path)
        info = meta.get("global", {})
        if info.get("thrumapper:kind") != KIND:
            raise SurveyFormatError("thrumapper:kind", f"expected 'iq', got {info.get('thrumapper:kind')!r}",
                                    path=self._meta_path)
        if info.get("core:datatype") != DATATYPE:
            raise SurveyFormatError("core:datatype", f"expected cf32_le, got {info.get('core:datatype')!r}",
                                    path=self._meta_path)
        self._sounding, self._frame_offset = sounding_from_metadata(info, self._meta_path)
        self._M = int(info.get("core:num_channels", 0))
        if self._M != self._sounding.num_rx:
            raise SurveyFormatError("core:num_channels", f"{self._M} but the radar has {self._sounding.num_rx} "
                                    "RX elements", path=self._meta_path)
        size = os.path.getsize(self._data_path) if os.path.exists(self._data_path) else -1
        if size < 0 or size % (8 * self._M):
            raise SurveyFormatError("sigmf-data", "missing, or not a whole number of samples of all channels",
                                    path=self._meta_path)
        self._data = np.memmap(self._data_path, dtype=FILE_DTYPE, mode="r").reshape(-1, self._M)
        self._tags = []
        for capture in meta.get("captures", []):
            start = int(capture["core:sample_start"])
            if "core:frequency" in capture:
                self._tags.append((start, KEY_RX_FREQ, pmt.from_double(float(capture["core:frequency"]))))
            if "thrumapper:rx_time" in capture:
                secs, frac = capture["thrumapper:rx_time"]
                self._tags.append((start, KEY_RX_TIME, pmt.make_tuple(pmt.from_uint64(int(secs)),
                                                                       pmt.from_double(float(frac)))))
        for note in meta.get("annotations", []):
            start = int(note["core:sample_start"])
            if "thrumapper:pose" in note:
                self._tags.append((start, KEY_POSE, pmt.init_f64vector(3, [float(v) for v in note["thrumapper:pose"]])))
            if "thrumapper:frame_type" in note:
                self._tags.append((start, KEY_FRAME_TYPE, pmt.intern(str(note["thrumapper:frame_type"]))))
        self._tags.sort(key=lambda t: t[0])
        self._repeat = bool(repeat)
        self._position = 0
        self._tag_index = 0
        gr.sync_block.__init__(self, name="iq_source", in_sig=None, out_sig=[np.complex64] * self._M)

    def sounding(self):
        return self._sounding

    def frame_offset(self):
        return self._frame_offset

    def num_samples(self):
        return int(self._data.shape[0])

    def work(self, input_items, output_items):
        total = self._data.shape[0]
        if self._position >= total:
            if not self._repeat or total == 0:
                return _WORK_DONE
            self._position = 0
            self._tag_index = 0
        count = min(len(output_items[0]), total - self._position)
        block = self._data[self._position:self._position + count]
        for m in range(self._M):
            output_items[m][:count] = block[:, m]
        base = self.nitems_written(0) - self._position
        while self._tag_index < len(self._tags) and self._tags[self._tag_index][0] < self._position + count:
            offset, key, value = self._tags[self._tag_index]
            for m in range(self._M):
                self.add_item_tag(m, base + offset, key, value)
            self._tag_index += 1
        self._position += count
        return count
