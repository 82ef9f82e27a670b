#
# SPDX-License-Identifier: GPL-3.0-or-later
#
"""Reading and writing CSI surveys: SigMF recordings with the `thrumapper` extension.

The contract is docs/FORMATS.md (`thrumapper:kind = "csi"`). `read_survey` checks every rule
of it and raises one `SurveyFormatError` naming the offending field; it memory-maps the data,
so a survey larger than RAM opens instantly. `write_survey` writes the same layout.

In memory the CSI is `csi[f, m, n]` (frame, RX element, subcarrier). On disk it is SigMF's
channel interleaving, element `(f*N + n)*M + m`, so the memory view is the file viewed as
(F, N, M) and transposed: no copy is made.
"""

import calendar
import datetime as _dt
import hashlib
import json
import math
import os
import re
import warnings
from dataclasses import dataclass, field

import numpy as np

try:
    import sigmf
    from sigmf import SigMFFile
    from sigmf.sigmffile import get_sigmf_filenames
except ImportError as _err:  # pragma: no cover - the project's set-up installs it
    raise ImportError(
        "gr-thrumapper needs the `sigmf` library (sigmf 1.x); run scripts/setup-debian.sh"
    ) from _err

import jsonschema

EXTENSION_NAME = "thrumapper"
EXTENSION_VERSION = "1.0.0"
KIND = "csi"
DATATYPE = "cf32_le"
FRAME_TYPES = ("survey", "rx_reference")
# Little-endian complex64 whatever the host: the file is cf32_le.
FILE_DTYPE = np.dtype("<c8")
_RECORDER = "gr-thrumapper"

# Fields that write_survey manages itself and extra_global may therefore not set.
_MANAGED_GLOBAL_KEYS = frozenset(
    {
        "core:datatype",
        "core:num_channels",
        "core:version",
        "core:extensions",
        "core:sha512",
        "core:offset",
        "core:dataset",
        "core:metadata_only",
        "core:trailing_bytes",
        "thrumapper:kind",
        "thrumapper:subcarrier_offsets_hz",
        "thrumapper:rx_elements",
        "thrumapper:tx_elements",
        "thrumapper:tx_weights",
        "thrumapper:system_delay_s",
        "thrumapper:wall_model",
    }
)

# Frames per chunk when scanning or writing data: about 16 MiB at M=8, N=128.
_CHUNK_BYTES = 16 << 20


class SurveyFormatError(ValueError):
    """A survey that breaks the contract of FORMATS.md.

    `field` is the offending field ("thrumapper:rx_elements", "core:sample_start",
    "sigmf-data" for the data file, "sigmf-meta" for the metadata file itself), `path` the
    metadata file, when known. The message starts with the field name.
    """

    def __init__(self, field, message, *, where=None, path=None):
        self.field = field
        self.where = where
        self.path = path
        text = f"{field}: {message}"
        if where is not None:
            text = f"{where} {text}"
        if path is not None:
            text = f"{text} (in {path})"
        super().__init__(text)


@dataclass(eq=False)
class Survey:
    """A CSI survey as `read_survey` returns it. Arrays are indexed by frame first."""

    meta_path: str
    data_path: str
    csi: np.ndarray = field(repr=False)  # (F, M, N) complex64, read-only memmap view
    subcarrier_offsets_hz: np.ndarray = field(repr=False)  # (N,) ascending
    center_frequencies_hz: np.ndarray = field(repr=False)  # (F,)
    rx_elements_m: np.ndarray = field(repr=False)  # (M, 2), robot frame
    tx_elements_m: np.ndarray = field(repr=False)  # (K, 2), robot frame
    tx_weights: np.ndarray = field(repr=False)  # (K,) complex128, global weights
    frame_tx_weights: np.ndarray = field(repr=False)  # (F, K) complex128
    poses: np.ndarray = field(repr=False)  # (F, 3) [x, y, heading]; NaN row: no pose
    frame_types: list = field(repr=False)  # F strings from FRAME_TYPES
    datetimes: list = field(repr=False)  # F ISO 8601 strings or None
    system_delay_s: float = None
    wall_model: dict = None
    global_info: dict = field(default_factory=dict, repr=False)

    @property
    def num_frames(self):
        return self.csi.shape[0]

    @property
    def num_rx(self):
        return self.csi.shape[1]

    @property
    def num_tx(self):
        return self.tx_elements_m.shape[0]

    @property
    def num_subcarriers(self):
        return self.csi.shape[2]

    def survey_frames(self):
        """Indices of the frames of type "survey", ascending."""
        return np.flatnonzero(np.asarray(self.frame_types, dtype=object) == "survey")

    def reference_frames(self):
        """Indices of the frames of type "rx_reference", ascending."""
        return np.flatnonzero(np.asarray(self.frame_types, dtype=object) == "rx_reference")


# ----------------------------------------------------------------------------------------
# Times: SigMF core:datetime <-> UHD-style rx_time (integer seconds, fractional seconds)
# ----------------------------------------------------------------------------------------
_DATETIME_RE = re.compile(
    r"^(\d{4})-(\d{2})-(\d{2})[Tt ](\d{2}):(\d{2}):(\d{2})(\.\d+)?([Zz]|[+-]\d{2}:\d{2})?$"
)


def datetime_to_rx_time(text):
    """Parse an ISO 8601 / RFC 3339 time into (whole seconds since the Unix epoch, fraction).

    Any number of fractional digits is kept (datetime.fromisoformat stops at microseconds).
    A time without an offset is taken as UTC, as SigMF allows only "Z". Raises ValueError.
    """
    match = _DATETIME_RE.match(text) if isinstance(text, str) else None
    if match is None:
        raise ValueError(f"not an ISO 8601 time YYYY-MM-DDTHH:MM:SS[.fff]Z: {text!r}")
    year, month, day, hour, minute, second = (int(g) for g in match.groups()[:6])
    # The constructor checks the calendar (month 13, 30 February...).
    _dt.datetime(year, month, day, hour, minute, second)
    seconds = calendar.timegm((year, month, day, hour, minute, second, 0, 0, 0))
    offset = match.group(8)
    if offset and offset not in ("Z", "z"):
        sign = 1 if offset[0] == "+" else -1
        seconds -= sign * (int(offset[1:3]) * 3600 + int(offset[4:6]) * 60)
    frac = float("0" + match.group(7)) if match.group(7) else 0.0
    return seconds, frac


def rx_time_to_datetime(seconds, frac=0.0):
    """Format (whole seconds since the Unix epoch, fraction) as SigMF's UTC time, to 1 ns."""
    seconds = int(seconds)
    nanoseconds = int(round(float(frac) * 1e9))
    seconds += nanoseconds // 1_000_000_000
    nanoseconds %= 1_000_000_000
    stamp = _dt.datetime.fromtimestamp(seconds, tz=_dt.timezone.utc)
    return stamp.strftime("%Y-%m-%dT%H:%M:%S") + f".{nanoseconds:09d}Z"


# ----------------------------------------------------------------------------------------
# Reading
# ----------------------------------------------------------------------------------------
def _is_number(value):
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _finite_number(value, name, where=None, path=None):
    if not _is_number(value) or not math.isfinite(value):
        raise SurveyFormatError(name, f"expected a finite number, got {value!r}", where=where, path=path)
    return float(value)


def _number_array(value, name, what, path, where=None):
    """A JSON list of finite numbers as float64, in one vectorised check."""
    if not isinstance(value, list) or not all(_is_number(v) for v in value):
        raise SurveyFormatError(name, f"expected a list of {what}, got {_short(value)}", where=where, path=path)
    array = np.asarray(value, dtype=np.float64)
    if not np.all(np.isfinite(array)):
        bad = int(np.flatnonzero(~np.isfinite(array))[0])
        raise SurveyFormatError(name, f"entry {bad} is not finite: {value[bad]!r}", where=where, path=path)
    return array


def _pairs(value, name, what, count, count_name, path, where=None):
    """A JSON list of `count` pairs of finite numbers as an (count, 2) float64 array."""
    if not isinstance(value, list):
        raise SurveyFormatError(name, f"expected a list of pairs {what}, got {_short(value)}", where=where, path=path)
    if count is not None and len(value) != count:
        raise SurveyFormatError(
            name, f"expected {count_name}={count} pairs {what}, got {len(value)}", where=where, path=path
        )
    if not value:
        raise SurveyFormatError(name, f"expected at least one pair {what}, got none", where=where, path=path)
    for i, pair in enumerate(value):
        if (
            not isinstance(pair, list)
            or len(pair) != 2
            or not all(_is_number(v) and math.isfinite(v) for v in pair)
        ):
            raise SurveyFormatError(
                name, f"entry {i} is not a pair {what} of finite numbers: {_short(pair)}", where=where, path=path
            )
    return np.asarray(value, dtype=np.float64).reshape(len(value), 2)


def _weights(value, name, count, path, where=None):
    pairs = _pairs(value, name, "[re, im]", count, "K", path, where=where)
    return pairs[:, 0] + 1j * pairs[:, 1]


def _short(value, limit=80):
    text = repr(value)
    return text if len(text) <= limit else text[: limit - 3] + "..."


def _check_extension(global_info, path):
    name = "core:extensions"
    extensions = global_info.get(name)
    if not isinstance(extensions, list):
        raise SurveyFormatError(
            name, f'expected a list declaring {{"name": "{EXTENSION_NAME}", ...}}, got {_short(extensions)}', path=path
        )
    entries = [e for e in extensions if isinstance(e, dict) and e.get("name") == EXTENSION_NAME]
    if not entries:
        raise SurveyFormatError(name, f'does not declare the "{EXTENSION_NAME}" extension', path=path)
    entry = entries[0]
    version = entry.get("version")
    # A 1.x writer only adds optional fields, which this reader ignores.
    if not isinstance(version, str) or not re.match(r"^1\.\d+\.\d+", version):
        raise SurveyFormatError(
            name, f'"{EXTENSION_NAME}" version must be {EXTENSION_VERSION} (1.x), got {version!r}', path=path
        )
    if entry.get("optional") is not False:
        raise SurveyFormatError(
            name, f'"{EXTENSION_NAME}" must be declared with "optional": false, got {entry.get("optional")!r}',
            path=path,
        )


def _check_wall_model(value, path):
    name = "thrumapper:wall_model"
    if not isinstance(value, dict):
        raise SurveyFormatError(name, f"expected an object, got {_short(value)}", path=path)
    model = {}
    for key in ("relative_permittivity", "thickness_m"):
        if key not in value:
            raise SurveyFormatError(name, f'missing "{key}"', path=path)
        number = value[key]
        if not _is_number(number) or not math.isfinite(number):
            raise SurveyFormatError(name, f'"{key}" must be a finite number, got {number!r}', path=path)
        model[key] = float(number)
    if model["relative_permittivity"] < 1.0:
        raise SurveyFormatError(
            name, f'"relative_permittivity" must be >= 1, got {model["relative_permittivity"]}', path=path
        )
    if model["thickness_m"] <= 0.0:
        raise SurveyFormatError(name, f'"thickness_m" must be > 0, got {model["thickness_m"]}', path=path)
    return model


def _schema_field(err):
    """The field a jsonschema error is about: the last key on its path."""
    keys = [k for k in err.absolute_path if isinstance(k, str)]
    if keys:
        return keys[-1]
    if err.validator == "required" and err.validator_value:
        missing = [k for k in err.validator_value if isinstance(err.instance, dict) and k not in err.instance]
        if missing:
            return missing[0]
    return "sigmf-meta"


def _sigmf_validate(metadata, path):
    """SigMF's own schema check, its failures turned into SurveyFormatError."""
    try:
        with warnings.catch_warnings():
            # Undeclared third-party namespaces are the other tool's business, not ours.
            warnings.simplefilter("ignore", DeprecationWarning)
            SigMFFile(metadata=metadata).validate()
    except jsonschema.exceptions.ValidationError as err:
        location = "/".join(str(k) for k in err.absolute_path)
        raise SurveyFormatError(
            _schema_field(err), f"SigMF schema: {err.message}" + (f" at {location}" if location else ""), path=path
        ) from None
    except sigmf.error.SigMFError as err:
        raise SurveyFormatError("sigmf-meta", f"SigMF: {err}", path=path) from None


def _load_json(meta_path):
    try:
        with open(meta_path, "rb") as handle:
            return json.load(handle)
    except FileNotFoundError:
        raise SurveyFormatError("sigmf-meta", f"metadata file {meta_path} does not exist") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as err:
        raise SurveyFormatError("sigmf-meta", f"malformed JSON in {meta_path}: {err}") from None


def read_survey(path, validate_values=True):
    """Open a CSI survey: NAME, NAME.sigmf-meta or NAME.sigmf-data.

    Checks every rule of FORMATS.md and SigMF's schema, and raises SurveyFormatError naming
    the field on the first failure. The CSI is memory-mapped, read-only. With
    validate_values, the data are also scanned (in chunks) for NaN/Inf, and checked against
    core:sha512 when the file gives one.
    """
    names = get_sigmf_filenames(os.fspath(path))
    meta_path, data_path = str(names["meta_fn"]), str(names["data_fn"])
    metadata = _load_json(meta_path)
    p = meta_path

    if not isinstance(metadata, dict):
        raise SurveyFormatError("sigmf-meta", "the top level must be a JSON object", path=p)
    global_info = metadata.get("global")
    if not isinstance(global_info, dict):
        raise SurveyFormatError("global", "missing or not an object", path=p)
    captures = metadata.get("captures")
    if not isinstance(captures, list):
        raise SurveyFormatError("captures", "missing or not a list", path=p)

    # Identity first: a file of another kind should be told so, not that it lacks CSI fields.
    version = global_info.get("core:version")
    if not isinstance(version, str) or not re.match(r"^1\.\d+\.\d+", version):
        raise SurveyFormatError("core:version", f"expected a SigMF 1.x version, got {version!r}", path=p)
    _check_extension(global_info, p)
    if "thrumapper:kind" not in global_info:
        raise SurveyFormatError("thrumapper:kind", f'missing; a CSI survey has "{KIND}"', path=p)
    kind = global_info["thrumapper:kind"]
    if kind != KIND:
        raise SurveyFormatError(
            "thrumapper:kind", f'unknown kind {kind!r} for a survey; expected "{KIND}"', path=p
        )
    for name in (
        "core:datatype",
        "core:num_channels",
        "thrumapper:subcarrier_offsets_hz",
        "thrumapper:rx_elements",
        "thrumapper:tx_elements",
        "thrumapper:tx_weights",
    ):
        if name not in global_info:
            raise SurveyFormatError(name, "required global field is missing", path=p)
    if global_info["core:datatype"] != DATATYPE:
        raise SurveyFormatError(
            "core:datatype", f'expected "{DATATYPE}", got {global_info["core:datatype"]!r}', path=p
        )
    num_rx = global_info["core:num_channels"]
    if not isinstance(num_rx, int) or isinstance(num_rx, bool) or num_rx < 1:
        raise SurveyFormatError("core:num_channels", f"expected a positive integer, got {num_rx!r}", path=p)
    # Byte-level layout is fixed by the contract: no headers or trailers in the data file.
    for name in ("core:trailing_bytes",):
        if global_info.get(name, 0) != 0:
            raise SurveyFormatError(name, "a survey's data file holds samples only; expected 0", path=p)
    if global_info.get("core:metadata_only") is True:
        raise SurveyFormatError("core:metadata_only", "a survey needs its data file", path=p)

    offsets_hz = _number_array(
        global_info["thrumapper:subcarrier_offsets_hz"], "thrumapper:subcarrier_offsets_hz", "numbers (Hz)", p
    )
    if offsets_hz.size == 0:
        raise SurveyFormatError("thrumapper:subcarrier_offsets_hz", "expected N >= 1 offsets, got none", path=p)
    if np.any(np.diff(offsets_hz) <= 0):
        bad = int(np.flatnonzero(np.diff(offsets_hz) <= 0)[0]) + 1
        raise SurveyFormatError(
            "thrumapper:subcarrier_offsets_hz",
            f"must be strictly ascending; entry {bad} ({offsets_hz[bad]}) follows {offsets_hz[bad - 1]}",
            path=p,
        )
    num_sc = offsets_hz.size
    rx_m = _pairs(global_info["thrumapper:rx_elements"], "thrumapper:rx_elements", "[x, y]", num_rx, "M", p)
    tx_m = _pairs(global_info["thrumapper:tx_elements"], "thrumapper:tx_elements", "[x, y]", None, "K", p)
    num_tx = tx_m.shape[0]
    tx_weights = _weights(global_info["thrumapper:tx_weights"], "thrumapper:tx_weights", num_tx, p)

    system_delay_s = None
    if "thrumapper:system_delay_s" in global_info:
        system_delay_s = _finite_number(global_info["thrumapper:system_delay_s"], "thrumapper:system_delay_s", path=p)
    wall_model = None
    if "thrumapper:wall_model" in global_info:
        wall_model = _check_wall_model(global_info["thrumapper:wall_model"], p)

    num_frames = len(captures)
    freqs_hz = np.empty(num_frames)
    poses = np.full((num_frames, 3), np.nan)
    frame_weights = np.empty((num_frames, num_tx), dtype=np.complex128)
    frame_weights[:] = tx_weights
    frame_types = []
    datetimes = []
    for f, capture in enumerate(captures):
        where = f"captures[{f}]"
        if not isinstance(capture, dict):
            raise SurveyFormatError("captures", f"entry {f} is not an object", path=p)
        if "core:sample_start" not in capture:
            raise SurveyFormatError("core:sample_start", "missing", where=where, path=p)
        start = capture["core:sample_start"]
        if start != f * num_sc or not isinstance(start, int) or isinstance(start, bool):
            raise SurveyFormatError(
                "core:sample_start",
                f"expected f*N = {f}*{num_sc} = {f * num_sc} (one capture per frame, in order), got {start!r}",
                where=where,
                path=p,
            )
        if capture.get("core:header_bytes", 0) != 0:
            raise SurveyFormatError("core:header_bytes", "a survey's data file holds samples only", where=where, path=p)
        if "core:frequency" not in capture:
            raise SurveyFormatError("core:frequency", "missing", where=where, path=p)
        freqs_hz[f] = _finite_number(capture["core:frequency"], "core:frequency", where, p)

        frame_type = capture.get("thrumapper:frame_type", "survey")
        if frame_type not in FRAME_TYPES:
            raise SurveyFormatError(
                "thrumapper:frame_type", f"unknown frame type {frame_type!r}; expected one of {FRAME_TYPES}",
                where=where, path=p,
            )
        frame_types.append(frame_type)

        pose = capture.get("thrumapper:pose")
        if pose is None:
            if frame_type == "survey":
                raise SurveyFormatError("thrumapper:pose", "missing on a survey frame", where=where, path=p)
        else:
            if (
                not isinstance(pose, list)
                or len(pose) != 3
                or not all(_is_number(v) and math.isfinite(v) for v in pose)
            ):
                raise SurveyFormatError(
                    "thrumapper:pose", f"expected [x, y, heading], three finite numbers, got {_short(pose)}",
                    where=where, path=p,
                )
            poses[f] = pose

        if "thrumapper:tx_weights" in capture:
            frame_weights[f] = _weights(capture["thrumapper:tx_weights"], "thrumapper:tx_weights", num_tx, p, where)

        stamp = capture.get("core:datetime")
        if stamp is not None:
            try:
                datetime_to_rx_time(stamp)
            except ValueError as err:
                raise SurveyFormatError("core:datetime", str(err), where=where, path=p) from None
        datetimes.append(stamp)

    _sigmf_validate(metadata, p)

    csi = _map_data(data_path, num_frames, num_rx, num_sc, p)
    if validate_values:
        _check_values(csi, data_path, global_info.get("core:sha512"), p)
    return Survey(
        meta_path=meta_path,
        data_path=data_path,
        csi=csi,
        subcarrier_offsets_hz=offsets_hz,
        center_frequencies_hz=freqs_hz,
        rx_elements_m=rx_m,
        tx_elements_m=tx_m,
        tx_weights=tx_weights,
        frame_tx_weights=frame_weights,
        poses=poses,
        frame_types=frame_types,
        datetimes=datetimes,
        system_delay_s=system_delay_s,
        wall_model=wall_model,
        global_info=global_info,
    )


def _map_data(data_path, num_frames, num_rx, num_sc, path):
    """The data file as a read-only (F, M, N) view of a (F, N, M) memmap."""
    if not os.path.isfile(data_path):
        raise SurveyFormatError("sigmf-data", f"data file {data_path} is missing", path=path)
    size = os.path.getsize(data_path)
    frame_bytes = FILE_DTYPE.itemsize * num_rx * num_sc
    whole, rest = divmod(size, frame_bytes)
    if rest:
        raise SurveyFormatError(
            "sigmf-data",
            f"{size} bytes is not a whole number of frames of M*N = {num_rx}*{num_sc} cf32 ({frame_bytes} bytes)",
            path=path,
        )
    if whole != num_frames:
        state = "truncated: " if whole < num_frames else ""
        raise SurveyFormatError(
            "sigmf-data", f"{state}holds {whole} frames but the captures list {num_frames}", path=path
        )
    if num_frames == 0:
        # np.memmap cannot map an empty file; an empty survey is still a survey.
        empty = np.zeros((0, num_sc, num_rx), dtype=FILE_DTYPE)
        empty.setflags(write=False)
        return empty.transpose(0, 2, 1)
    mapped = np.memmap(data_path, dtype=FILE_DTYPE, mode="r", shape=(num_frames, num_sc, num_rx))
    return mapped.transpose(0, 2, 1)


def _check_values(csi, data_path, sha512, path):
    """Scan the data for NaN/Inf chunk by chunk (and hash it when the file gives a hash)."""
    file_order = csi.transpose(0, 2, 1)  # back to (F, N, M): contiguous frames of the file
    num_frames = file_order.shape[0]
    if num_frames == 0:
        return
    frame_floats = 2 * file_order.shape[1] * file_order.shape[2]
    step = max(1, _CHUNK_BYTES // (4 * frame_floats))
    hasher = hashlib.sha512() if sha512 is not None else None
    for start in range(0, num_frames, step):
        chunk = np.asarray(file_order[start : start + step])
        floats = chunk.view(np.float32).reshape(chunk.shape[0], frame_floats)
        finite = np.isfinite(floats).all(axis=1)
        if not finite.all():
            bad = start + int(np.argmin(finite))
            raise SurveyFormatError(
                "sigmf-data", f"frame {bad} holds NaN or Inf CSI values ({data_path})", path=path
            )
        if hasher is not None:
            hasher.update(memoryview(chunk).cast("B"))
    if hasher is not None and hasher.hexdigest() != str(sha512).lower():
        raise SurveyFormatError("core:sha512", f"does not match the data file {data_path}", path=path)


def group_frames_by_pose(survey, atol=1e-9):
    """Runs of consecutive survey frames at one pose: [(frame_indices, pose (3,)), ...].

    rx_reference frames are left out and do not break a run (a reference shot taken without
    moving leaves the robot where it was), and so are, on a radar of more than one TX
    element, the frames sounded with one element alone: the TX calibration
    (tx_calibration.py), not the survey's beam. Poses are equal when every component is
    within atol.
    """
    if __package__:
        from .tx_calibration import single_element_frames
    else:  # imported as a plain file
        from tx_calibration import single_element_frames
    frames = np.setdiff1d(survey.survey_frames(), single_element_frames(survey)[0])
    if frames.size == 0:
        return []
    poses = survey.poses[frames]
    moved = np.any(np.abs(np.diff(poses, axis=0)) > atol, axis=1)
    starts = np.concatenate(([0], np.flatnonzero(moved) + 1))
    groups = np.split(frames, starts[1:])
    return [(group, poses[start].copy()) for group, start in zip(groups, starts)]


# ----------------------------------------------------------------------------------------
# Writing
# ----------------------------------------------------------------------------------------
def _finite_array(value, name, shape, dtype=np.float64):
    """`value` as an array of `shape` (None matches any length), every entry finite."""
    try:
        array = np.asarray(value, dtype=dtype)
    except (TypeError, ValueError) as err:
        raise ValueError(f"{name}: expected numbers of shape {shape}: {err}") from None
    if array.ndim != len(shape) or any(s is not None and s != a for s, a in zip(shape, array.shape)):
        raise ValueError(f"{name}: expected shape {shape}, got {array.shape}")
    if not np.all(np.isfinite(array)):
        raise ValueError(f"{name}: every value must be finite")
    return array


def check_radar(subcarrier_offsets_hz, rx_elements_m, tx_elements_m, tx_weights=None):
    """Normalise and check the description common to write_survey and survey_sink.

    Returns (offsets_hz (N,), rx_m (M, 2), tx_m (K, 2), tx_weights (K,) complex128);
    tx_weights None means all ones. Raises ValueError naming the argument.
    """
    offsets_hz = _finite_array(subcarrier_offsets_hz, "subcarrier_offsets_hz", (None,))
    if offsets_hz.size == 0:
        raise ValueError("subcarrier_offsets_hz: expected N >= 1 offsets")
    if np.any(np.diff(offsets_hz) <= 0):
        raise ValueError("subcarrier_offsets_hz: must be strictly ascending")
    rx_m = _finite_array(rx_elements_m, "rx_elements_m", (None, 2))
    tx_m = _finite_array(tx_elements_m, "tx_elements_m", (None, 2))
    if rx_m.shape[0] == 0 or tx_m.shape[0] == 0:
        raise ValueError("rx_elements_m, tx_elements_m: each array needs at least one element")
    num_tx = tx_m.shape[0]
    if tx_weights is None:
        weights = np.ones(num_tx, dtype=np.complex128)
    else:
        weights = _finite_array(tx_weights, "tx_weights", (num_tx,), np.complex128)
    return offsets_hz, rx_m, tx_m, weights


def _check_wall_model_arg(wall_model):
    if wall_model is None:
        return None
    try:
        return _check_wall_model(dict(wall_model), None)
    except (TypeError, ValueError) as err:
        raise ValueError(f"wall_model: {err}") from None


def _pair_list(array):
    return [[float(a), float(b)] for a, b in array]


def _weight_list(weights):
    return [[float(w.real), float(w.imag)] for w in weights]


def build_global(
    *,
    offsets_hz,
    rx_m,
    tx_m,
    tx_weights,
    system_delay_s=None,
    wall_model=None,
    description=None,
    author=None,
    extra_global=None,
    sha512=None,
):
    """The global object of a CSI survey from checked arrays (see check_radar)."""
    info = {}
    if extra_global:
        clash = sorted(set(extra_global) & _MANAGED_GLOBAL_KEYS)
        if clash:
            raise ValueError(f"extra_global: may not set {clash}; they are written from the arguments")
        try:
            # A JSON round trip: plain types only, and no NaN (which is not JSON).
            info.update(json.loads(json.dumps(extra_global, allow_nan=False)))
        except (TypeError, ValueError) as err:
            raise ValueError(f"extra_global: not JSON-serialisable: {err}") from None
    info.update(
        {
            "core:datatype": DATATYPE,
            "core:num_channels": int(rx_m.shape[0]),
            "core:extensions": [{"name": EXTENSION_NAME, "version": EXTENSION_VERSION, "optional": False}],
            "core:recorder": info.get("core:recorder", _RECORDER),
            "thrumapper:kind": KIND,
            "thrumapper:subcarrier_offsets_hz": [float(v) for v in offsets_hz],
            "thrumapper:rx_elements": _pair_list(rx_m),
            "thrumapper:tx_elements": _pair_list(tx_m),
            "thrumapper:tx_weights": _weight_list(tx_weights),
        }
    )
    if system_delay_s is not None:
        numeric = isinstance(system_delay_s, (int, float, np.integer, np.floating))
        if isinstance(system_delay_s, (bool, np.bool_)) or not numeric or not math.isfinite(system_delay_s):
            raise ValueError(f"system_delay_s: expected a finite number, got {system_delay_s!r}")
        info["thrumapper:system_delay_s"] = float(system_delay_s)
    model = _check_wall_model_arg(wall_model)
    if model is not None:
        info["thrumapper:wall_model"] = model
    if description is not None:
        info["core:description"] = str(description)
    if author is not None:
        info["core:author"] = str(author)
    if sha512 is not None:
        info["core:sha512"] = sha512
    return info


def build_capture(frame, num_subcarriers, frequency_hz, pose=None, frame_type="survey", tx_weights=None, datetime=None):
    """One capture object; pose None (or NaN) and tx_weights None are left out."""
    capture = {"core:sample_start": int(frame) * int(num_subcarriers), "core:frequency": float(frequency_hz)}
    if datetime is not None:
        capture["core:datetime"] = datetime
    if frame_type != "survey":
        capture["thrumapper:frame_type"] = frame_type
    if pose is not None and np.all(np.isfinite(pose)):
        capture["thrumapper:pose"] = [float(v) for v in pose]
    if tx_weights is not None:
        capture["thrumapper:tx_weights"] = _weight_list(tx_weights)
    return capture


def write_meta(meta_path, global_info, captures):
    """Write the metadata with the sigmf library (which also checks it against the schema).

    The captures go in whole: SigMFFile.add_capture merges and re-sorts on every call, which
    is quadratic in the number of frames (seconds at 5000 frames, minutes for a long survey).
    """
    meta = SigMFFile(metadata={"global": global_info, "captures": captures, "annotations": []})
    meta.tofile(meta_path, overwrite=True)
    return meta_path


def write_survey(
    path,
    csi,
    *,
    subcarrier_offsets_hz,
    center_frequency_hz,
    rx_elements_m,
    tx_elements_m,
    tx_weights=None,
    poses=None,
    frame_types=None,
    frame_tx_weights=None,
    system_delay_s=None,
    wall_model=None,
    datetimes=None,
    description=None,
    author=None,
    extra_global=None,
):
    """Write a CSI survey: NAME.sigmf-data, then NAME.sigmf-meta. Returns the meta path.

    csi is (F, M, N) complex (stored as complex64); center_frequency_hz a scalar or (F,);
    poses (F, 3) with a NaN row where a frame has no pose (every survey frame needs one);
    frame_types F strings ("survey" by default); frame_tx_weights (F, K), stored per capture
    only where a frame's weights differ from tx_weights; datetimes F ISO 8601 strings or
    None. Existing files are replaced. Raises ValueError naming the argument.
    """
    csi = np.asarray(csi)
    if csi.ndim != 3 or not np.issubdtype(csi.dtype, np.number):
        raise ValueError(f"csi: expected a numeric (F, M, N) array, got shape {csi.shape} of {csi.dtype}")
    num_frames, num_rx, num_sc = csi.shape
    offsets_hz, rx_m, tx_m, weights = check_radar(subcarrier_offsets_hz, rx_elements_m, tx_elements_m, tx_weights)
    if offsets_hz.size != num_sc:
        raise ValueError(f"subcarrier_offsets_hz: csi has N={num_sc} subcarriers, got {offsets_hz.size} offsets")
    if rx_m.shape[0] != num_rx:
        raise ValueError(f"rx_elements_m: csi has M={num_rx} RX elements, got {rx_m.shape[0]} positions")
    num_tx = tx_m.shape[0]

    freqs_hz = np.asarray(center_frequency_hz, dtype=np.float64)
    if freqs_hz.ndim == 0:
        freqs_hz = np.full(num_frames, float(freqs_hz))
    freqs_hz = _finite_array(freqs_hz, "center_frequency_hz", (num_frames,))

    if frame_types is None:
        frame_types = ["survey"] * num_frames
    frame_types = list(frame_types)
    if len(frame_types) != num_frames:
        raise ValueError(f"frame_types: expected {num_frames} entries, got {len(frame_types)}")
    unknown = sorted({t for t in frame_types if t not in FRAME_TYPES}, key=str)
    if unknown:
        raise ValueError(f"frame_types: unknown {unknown}; expected one of {FRAME_TYPES}")
    is_survey = np.array([t == "survey" for t in frame_types], dtype=bool)

    if poses is None:
        poses = np.full((num_frames, 3), np.nan)
    poses = np.asarray(poses, dtype=np.float64)
    if poses.shape != (num_frames, 3):
        raise ValueError(f"poses: expected shape ({num_frames}, 3), got {poses.shape}")
    has_pose = np.all(np.isfinite(poses), axis=1)
    no_pose = np.all(np.isnan(poses), axis=1)
    if not np.all(has_pose | no_pose):
        bad = int(np.flatnonzero(~(has_pose | no_pose))[0])
        raise ValueError(f"poses: row {bad} must be all finite or all NaN (no pose), got {poses[bad]}")
    if np.any(is_survey & ~has_pose):
        bad = int(np.flatnonzero(is_survey & ~has_pose)[0])
        raise ValueError(f"poses: survey frame {bad} has no pose")

    if frame_tx_weights is None:
        overrides = np.zeros(num_frames, dtype=bool)
    else:
        frame_tx_weights = _finite_array(frame_tx_weights, "frame_tx_weights", (num_frames, num_tx), np.complex128)
        overrides = np.any(frame_tx_weights != weights, axis=1)

    if datetimes is None:
        datetimes = [None] * num_frames
    datetimes = list(datetimes)
    if len(datetimes) != num_frames:
        raise ValueError(f"datetimes: expected {num_frames} entries, got {len(datetimes)}")
    for f, stamp in enumerate(datetimes):
        if stamp is not None:
            try:
                datetime_to_rx_time(stamp)
            except ValueError as err:
                raise ValueError(f"datetimes[{f}]: {err}") from None

    names = get_sigmf_filenames(os.fspath(path))
    meta_path, data_path = str(names["meta_fn"]), str(names["data_fn"])

    # Check the global fields before touching the disk.
    build_global(offsets_hz=offsets_hz, rx_m=rx_m, tx_m=tx_m, tx_weights=weights, system_delay_s=system_delay_s,
                 wall_model=wall_model, description=description, author=author, extra_global=extra_global)

    # Chunks of frames keep the temporary copies small on large surveys.
    step = max(1, _CHUNK_BYTES // max(1, FILE_DTYPE.itemsize * num_rx * num_sc))
    for start in range(0, num_frames, step):
        # Checked as stored: a huge complex128 value overflows to Inf in complex64.
        chunk = csi[start : start + step].astype(FILE_DTYPE, copy=False)
        finite = np.isfinite(chunk).reshape(-1, num_rx * num_sc).all(axis=1)
        if not finite.all():
            raise ValueError(f"csi: frame {start + int(np.argmin(finite))} holds NaN or Inf")

    # Data: frames transposed to the file's (N, M) order, hashed as they go.
    hasher = hashlib.sha512()
    with open(data_path, "wb") as handle:
        for start in range(0, num_frames, step):
            chunk = np.ascontiguousarray(csi[start : start + step].transpose(0, 2, 1), dtype=FILE_DTYPE)
            hasher.update(memoryview(chunk).cast("B"))
            handle.write(memoryview(chunk).cast("B"))

    global_info = build_global(
        offsets_hz=offsets_hz, rx_m=rx_m, tx_m=tx_m, tx_weights=weights, system_delay_s=system_delay_s,
        wall_model=wall_model, description=description, author=author, extra_global=extra_global,
        sha512=hasher.hexdigest(),
    )
    captures = [
        build_capture(
            f,
            num_sc,
            freqs_hz[f],
            pose=poses[f] if has_pose[f] else None,
            frame_type=frame_types[f],
            tx_weights=frame_tx_weights[f] if overrides[f] else None,
            datetime=datetimes[f],
        )
        for f in range(num_frames)
    ]
    return write_meta(meta_path, global_info, captures)
