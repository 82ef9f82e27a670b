#
# SPDX-License-Identifier: GPL-3.0-or-later
#
"""GNU Radio blocks that replay and record CSI surveys (docs/survey-io.md).

Items are CSI frames: one vector of M*N gr_complex per frame, element-major (index m*N + n,
an M×N row-major matrix), the layout every block of the module takes. Stream tags carry the
frame's metadata; the pose also goes out as a message, for blocks that take poses by message.
"""

import hashlib
import os
import threading

import numpy as np
import pmt
from gnuradio import gr

if __package__:
    from .survey import (
        FILE_DTYPE,
        FRAME_TYPES,
        build_capture,
        build_global,
        check_radar,
        datetime_to_rx_time,
        read_survey,
        rx_time_to_datetime,
        write_meta,
    )
    from .tx_calibration import single_element_frames
else:  # imported as a plain file, before the package is built
    from survey import (
        FILE_DTYPE,
        FRAME_TYPES,
        build_capture,
        build_global,
        check_radar,
        datetime_to_rx_time,
        read_survey,
        rx_time_to_datetime,
        write_meta,
    )
    from tx_calibration import single_element_frames
from sigmf.sigmffile import get_sigmf_filenames

# Tag and message keys, shared by the source and the sink.
KEY_FRAME_INDEX = pmt.intern("frame_index")
KEY_POSE = pmt.intern("pose")
KEY_RX_TIME = pmt.intern("rx_time")
KEY_RX_FREQ = pmt.intern("rx_freq")
KEY_FRAME_TYPE = pmt.intern("frame_type")
KEY_TX_WEIGHTS = pmt.intern("tx_weights")
WEIGHTS_PORT = pmt.intern("weights")
KEY_X = pmt.intern("x")
KEY_Y = pmt.intern("y")
KEY_HEADING = pmt.intern("heading")
POSE_PORT = pmt.intern("pose")
# gr.WORK_DONE is an enum in Python; the gateway compares work()'s result with ints.
_WORK_DONE = int(gr.WORK_DONE)


def pose_message(frame_index, pose):
    """The pose message: a dict {frame_index: long, pose: f64vector, x, y, heading: double}."""
    x_m, y_m, heading_rad = (float(v) for v in pose)
    msg = pmt.make_dict()
    msg = pmt.dict_add(msg, KEY_FRAME_INDEX, pmt.from_long(int(frame_index)))
    msg = pmt.dict_add(msg, KEY_POSE, pmt.init_f64vector(3, [x_m, y_m, heading_rad]))
    msg = pmt.dict_add(msg, KEY_X, pmt.from_double(x_m))
    msg = pmt.dict_add(msg, KEY_Y, pmt.from_double(y_m))
    msg = pmt.dict_add(msg, KEY_HEADING, pmt.from_double(heading_rad))
    return msg


def pose_from_pmt(value):
    """[x, y, heading] from a pose tag or message, or None when it holds no finite pose.

    Takes an f64vector of 3, a dict with "pose" or with "x", "y", "heading", or a PDU pair
    whose car is such a dict.
    """
    if pmt.is_pair(value) and not pmt.is_dict(value):
        value = pmt.car(value)  # a PDU: the metadata dict holds the pose
    pose = None
    if pmt.is_f64vector(value):
        pose = np.asarray(pmt.f64vector_elements(value), dtype=np.float64)
    elif pmt.is_dict(value):
        if pmt.dict_has_key(value, KEY_POSE):
            return pose_from_pmt(pmt.dict_ref(value, KEY_POSE, pmt.PMT_NIL))
        parts = [pmt.dict_ref(value, key, pmt.PMT_NIL) for key in (KEY_X, KEY_Y, KEY_HEADING)]
        if all(pmt.is_number(p) for p in parts):
            pose = np.array([pmt.to_double(p) for p in parts])
    if pose is None or pose.shape != (3,) or not np.all(np.isfinite(pose)):
        return None
    return pose


def _rx_time_pmt(stamp):
    """core:datetime as UHD's rx_time: (uint64 whole seconds since the epoch, double fraction)."""
    seconds, frac = datetime_to_rx_time(stamp)
    return pmt.make_tuple(pmt.from_uint64(seconds), pmt.from_double(frac))


def _select_frames(survey, frame_types):
    """Frame indices to play: "survey", "rx_reference", "all", or a list of types."""
    if isinstance(frame_types, str):
        wanted = FRAME_TYPES if frame_types == "all" else (frame_types,)
    else:
        wanted = tuple(frame_types)
    unknown = [t for t in wanted if t not in FRAME_TYPES]
    if unknown:
        raise ValueError(f"frame_types: unknown {unknown}; expected 'all' or types from {FRAME_TYPES}")
    types = np.asarray(survey.frame_types, dtype=object)
    frames = np.flatnonzero(np.isin(types, list(wanted)))
    if frame_types == "survey":
        # The TX calibration's single-element frames are not the survey's beam: "all" plays them.
        frames = np.setdiff1d(frames, single_element_frames(survey)[0])
    return frames


class survey_source(gr.sync_block):
    """Replays a CSI survey as a stream of CSI frames.

    Output: one vector of M*N gr_complex per frame, element-major (index m*N + n).
    Tags on every item: "frame_index" (uint64), "pose" (f64vector [x, y, heading], on frames
    that have one), "rx_freq" (double, the frame's core:frequency), "frame_type" (symbol),
    "rx_time" (tuple (uint64 seconds, double fraction), when the frame has a core:datetime),
    and "tx_weights" (c64vector) on frames whose weights override the global ones.
    Message port "pose": a dict {frame_index, pose, x, y, heading} whenever the pose changes.
    Message port "weights": at start, a dict {"weights": c32vector} with the survey's global TX
    weights (the form projection_canceller and the sounder take).
    The flowgraph ends after the last frame unless repeat.

    frame_types: "survey" (default: the survey frames, without a TX calibration's frames sounded
    with one element alone), "rx_reference", "all", or a list of frame types.
    num_rx, num_subcarriers: when given, the M and N the flowgraph expects (GRC must know
    the vector length before the file is opened); a survey of another shape is refused.
    """

    def __init__(self, path, repeat=False, frame_types="survey", num_rx=None, num_subcarriers=None):
        self._survey = read_survey(path)
        survey = self._survey
        expected = (("num_rx", num_rx, survey.num_rx), ("num_subcarriers", num_subcarriers, survey.num_subcarriers))
        for name, wanted, actual in expected:
            if wanted is not None and int(wanted) != actual:
                raise ValueError(f"survey_source: {name}={wanted} but {survey.meta_path} has {actual}")
        self._frames = _select_frames(survey, frame_types)
        if self._frames.size == 0:
            raise ValueError(f"survey_source: {survey.meta_path} has no frames of type {frame_types!r}")
        self._num_rx = survey.num_rx
        self._num_sc = survey.num_subcarriers
        gr.sync_block.__init__(
            self, name="survey_source", in_sig=None, out_sig=[(np.complex64, self._num_rx * self._num_sc)]
        )
        self.message_port_register_out(POSE_PORT)
        self.message_port_register_out(WEIGHTS_PORT)
        self._repeat = bool(repeat)
        self._position = 0  # next entry of self._frames to play
        self._last_pose = None
        # The file's own (F, N, M) order: a gather reads whole frames contiguously.
        self._file_order = survey.csi.transpose(0, 2, 1)
        self._srcid = pmt.intern(self.alias())
        # Per-frame tag values, made once: work() then only attaches them.
        self._rx_times = [None if stamp is None else _rx_time_pmt(stamp) for stamp in survey.datetimes]
        overrides = np.any(survey.frame_tx_weights != survey.tx_weights, axis=1)
        self._weight_tags = [
            pmt.init_c64vector(survey.num_tx, [complex(w) for w in survey.frame_tx_weights[f]])
            if overrides[f]
            else None
            for f in range(survey.num_frames)
        ]
        self._type_tags = {t: pmt.intern(t) for t in FRAME_TYPES}

    def survey(self):
        """The Survey being played."""
        return self._survey

    def start(self):
        weights = [complex(w) for w in self._survey.tx_weights]
        msg = pmt.dict_add(pmt.make_dict(), pmt.intern("weights"), pmt.init_c32vector(len(weights), weights))
        self.message_port_pub(WEIGHTS_PORT, msg)
        return gr.sync_block.start(self)

    def num_frames(self):
        """Number of frames played per pass."""
        return int(self._frames.size)

    def num_rx(self):
        return self._num_rx

    def num_subcarriers(self):
        return self._num_sc

    def work(self, input_items, output_items):
        out = output_items[0]
        total = self._frames.size
        if self._position >= total:
            if not self._repeat:
                return _WORK_DONE
            self._position = 0
        count = min(len(out), total - self._position)
        frames = self._frames[self._position : self._position + count]
        self._position += count
        # (k, N, M) from the file, written transposed into the (k, M, N) element-major items.
        np.copyto(
            out[:count].reshape(count, self._num_rx, self._num_sc),
            self._file_order[frames].transpose(0, 2, 1),
        )
        survey = self._survey
        first = self.nitems_written(0)
        for i, f in enumerate(frames):
            offset = first + i
            self.add_item_tag(0, offset, KEY_FRAME_INDEX, pmt.from_uint64(int(f)), self._srcid)
            frequency_hz = float(survey.center_frequencies_hz[f])
            self.add_item_tag(0, offset, KEY_RX_FREQ, pmt.from_double(frequency_hz), self._srcid)
            self.add_item_tag(0, offset, KEY_FRAME_TYPE, self._type_tags[survey.frame_types[f]], self._srcid)
            if self._rx_times[f] is not None:
                self.add_item_tag(0, offset, KEY_RX_TIME, self._rx_times[f], self._srcid)
            if self._weight_tags[f] is not None:
                self.add_item_tag(0, offset, KEY_TX_WEIGHTS, self._weight_tags[f], self._srcid)
            pose = survey.poses[f]
            if np.all(np.isfinite(pose)):
                self.add_item_tag(0, offset, KEY_POSE, pmt.init_f64vector(3, [float(v) for v in pose]), self._srcid)
                if self._last_pose is None or not np.array_equal(pose, self._last_pose):
                    self._last_pose = pose.copy()
                    self.message_port_pub(POSE_PORT, pose_message(f, pose))
        return count


class survey_sink(gr.sync_block):
    """Records a stream of CSI frames, with their poses, as a CSI survey.

    Input: one vector of M*N gr_complex per frame, element-major (index m*N + n).
    The pose of a frame is the latest one seen, from a "pose" tag on the items or a message
    on the "pose" port (a dict with "pose" or "x", "y", "heading", or an f64vector).
    Also honoured per item: "rx_time" (-> core:datetime), "frame_type" ("rx_reference"
    frames need no pose), "tx_weights"; and "rx_freq" (held until the next one; until then
    center_frequency_hz).

    The data are appended to NAME.sigmf-data as frames arrive; NAME.sigmf-meta is written on
    stop(). Frames holding NaN/Inf, and survey frames before any pose is known, are skipped,
    logged and counted (skipped_frames()). Existing files are replaced on start().
    """

    def __init__(
        self,
        path,
        num_rx,
        num_subcarriers,
        subcarrier_offsets_hz,
        center_frequency_hz,
        rx_elements_m,
        tx_elements_m,
        tx_weights=None,
        system_delay_s=None,
        wall_model=None,
        description=None,
        author=None,
    ):
        offsets_hz, rx_m, tx_m, weights = check_radar(subcarrier_offsets_hz, rx_elements_m, tx_elements_m, tx_weights)
        num_rx, num_subcarriers = int(num_rx), int(num_subcarriers)
        if rx_m.shape[0] != num_rx:
            raise ValueError(f"rx_elements_m: expected num_rx={num_rx} positions, got {rx_m.shape[0]}")
        if offsets_hz.size != num_subcarriers:
            raise ValueError(
                f"subcarrier_offsets_hz: expected num_subcarriers={num_subcarriers}, got {offsets_hz.size}"
            )
        center_frequency_hz = float(center_frequency_hz)
        if not np.isfinite(center_frequency_hz):
            raise ValueError("center_frequency_hz: must be finite")
        # Fails now, not at stop(), on a bad wall model or delay.
        self._global_args = dict(
            offsets_hz=offsets_hz, rx_m=rx_m, tx_m=tx_m, tx_weights=weights, system_delay_s=system_delay_s,
            wall_model=wall_model, description=description, author=author,
        )
        build_global(**self._global_args)
        names = get_sigmf_filenames(os.fspath(path))
        self._meta_path, self._data_path = str(names["meta_fn"]), str(names["data_fn"])

        gr.sync_block.__init__(
            self, name="survey_sink", in_sig=[(np.complex64, num_rx * num_subcarriers)], out_sig=None
        )
        self.message_port_register_in(POSE_PORT)
        self.set_msg_handler(POSE_PORT, self.handle_pose)

        self._num_rx, self._num_sc, self._num_tx = num_rx, num_subcarriers, tx_m.shape[0]
        self._default_frequency_hz = center_frequency_hz
        self._tx_weights = weights
        self._lock = threading.Lock()  # messages arrive on another thread than work()
        self._handle = None
        self._reset()

    def _reset(self):
        self._pose = None
        self._frequency_hz = self._default_frequency_hz
        self._captures = []
        self._hasher = hashlib.sha512()
        self._skipped_nonfinite = 0
        self._skipped_no_pose = 0

    def meta_path(self):
        return self._meta_path

    def data_path(self):
        return self._data_path

    def frames_written(self):
        """Frames recorded so far."""
        with self._lock:
            return len(self._captures)

    def skipped_frames(self):
        """Frames not recorded: NaN/Inf CSI, or a survey frame before any pose."""
        with self._lock:
            return self._skipped_nonfinite + self._skipped_no_pose

    def skipped_nonfinite(self):
        with self._lock:
            return self._skipped_nonfinite

    def skipped_no_pose(self):
        with self._lock:
            return self._skipped_no_pose

    def handle_pose(self, msg):
        pose = pose_from_pmt(msg)
        if pose is None:
            text = pmt.write_string(msg)[:200]
            self.logger.warn(f"ignoring a pose message that holds no finite [x, y, heading]: {text}")
            return
        with self._lock:
            self._pose = pose

    def start(self):
        with self._lock:
            self._reset()
            self._handle = open(self._data_path, "wb")
        return True

    def stop(self):
        with self._lock:
            if self._handle is None:
                return True
            self._handle.close()
            self._handle = None
            global_info = build_global(**self._global_args, sha512=self._hasher.hexdigest())
            write_meta(self._meta_path, global_info, self._captures)
            skipped = self._skipped_nonfinite + self._skipped_no_pose
        if skipped:
            self.logger.warn(
                f"{self._meta_path}: skipped {skipped} frames "
                f"({self._skipped_nonfinite} with NaN/Inf, {self._skipped_no_pose} before any pose)"
            )
        return True

    def _log_skip(self, item, count, reason):
        # The first skip, then every 1000th: a long run of bad frames must not flood the log.
        if count == 1 or count % 1000 == 0:
            self.logger.warn(f"skipping input item {item}: {reason} ({count} so far)")

    def work(self, input_items, output_items):
        frames = input_items[0]
        count = len(frames)
        first = self.nitems_read(0)
        tags_at = {}
        for tag in self.get_tags_in_window(0, 0, count):
            tags_at.setdefault(tag.offset - first, []).append(tag)
        finite = np.isfinite(frames.view(np.float32)).reshape(count, -1).all(axis=1)

        keep = np.zeros(count, dtype=bool)
        with self._lock:
            if self._handle is None:
                return count
            for i in range(count):
                frame_type, datetime, weights = "survey", None, None
                for tag in tags_at.get(i, ()):
                    key = pmt.symbol_to_string(tag.key)
                    if key == "pose":
                        pose = pose_from_pmt(tag.value)
                        if pose is not None:
                            self._pose = pose
                    elif key == "rx_freq" and pmt.is_number(tag.value):
                        self._frequency_hz = pmt.to_double(tag.value)
                    elif key == "rx_time" and pmt.is_tuple(tag.value) and pmt.length(tag.value) == 2:
                        secs = pmt.tuple_ref(tag.value, 0)
                        frac = pmt.tuple_ref(tag.value, 1)
                        secs = pmt.to_uint64(secs) if pmt.is_uint64(secs) else pmt.to_long(secs)
                        datetime = rx_time_to_datetime(secs, pmt.to_double(frac))
                    elif key == "frame_type" and pmt.is_symbol(tag.value):
                        name = pmt.symbol_to_string(tag.value)
                        frame_type = name if name in FRAME_TYPES else "survey"
                    elif key == "tx_weights" and pmt.is_c64vector(tag.value):
                        values = np.asarray(pmt.c64vector_elements(tag.value), dtype=np.complex128)
                        if values.shape == (self._num_tx,) and np.all(np.isfinite(values)):
                            weights = values if np.any(values != self._tx_weights) else None
                if not finite[i]:
                    self._skipped_nonfinite += 1
                    self._log_skip(first + i, self._skipped_nonfinite, "CSI holds NaN/Inf")
                    continue
                if frame_type == "survey" and self._pose is None:
                    self._skipped_no_pose += 1
                    self._log_skip(first + i, self._skipped_no_pose, "survey frame before any pose")
                    continue
                keep[i] = True
                self._captures.append(
                    build_capture(
                        len(self._captures),
                        self._num_sc,
                        self._frequency_hz,
                        pose=self._pose if frame_type == "survey" else None,
                        frame_type=frame_type,
                        tx_weights=weights,
                        datetime=datetime,
                    )
                )
            if keep.any():
                # Element-major items (k, M, N) to the file's (k, N, M) channel interleaving.
                kept = frames[keep].reshape(-1, self._num_rx, self._num_sc).transpose(0, 2, 1)
                data = np.ascontiguousarray(kept, dtype=FILE_DTYPE)
                self._hasher.update(memoryview(data).cast("B"))
                self._handle.write(memoryview(data).cast("B"))
                # On disk now: a crash loses the metadata, not the frames already seen.
                self._handle.flush()
        return count
