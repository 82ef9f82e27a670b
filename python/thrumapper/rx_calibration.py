#
# SPDX-License-Identifier: GPL-3.0-or-later
#
"""RX chain calibration of a CSI survey from its rx_reference frames (FORMATS.md).

An rx_reference frame holds H[m, n] = β_m(f_n)·s(f_n) + noise: one reference split equally
into every RX chain. The ratio of two channels is therefore β_m/β_0, whatever s is; only the
chains' *relative* gains, phases and delays can be measured, and only they matter to the
array processing (a factor common to every channel is one more complex gain per path, and a
common delay is part of the system delay).

The chains follow FORMATS.md's model β_m(f) = g_m·e^{jφ_m}·e^{−j2πfδ_m}: per channel, the
unwrapped phase of the frame-averaged ratio to the channel mean is fitted with a line over
frequency (phase and delay) and the log-amplitude with its mean (gain). The fit ignores the
subcarriers next to DC, where the radio's DC offset adds to the reference; that offset is then
the reference minus the fitted chain response there, and is removed from every frame.
`model=False` keeps the frame-averaged ratio per channel and subcarrier instead (chains with
ripple across the band), at the cost of the reference's noise.
"""

import math
from dataclasses import dataclass, replace

import numpy as np


@dataclass(eq=False)
class RxCalibration:
    """Relative RX chain responses and the correction that removes them.

    gain_db, phase_rad, delay_s: (M,) per channel, relative to the channels' mean (mean of the
    gains in dB, of the phases and of the delays is zero). correction: (M, N) complex, the
    factor that multiplies the CSI of channel m, subcarrier n. dc_offset: (M,) complex, added by
    the radio on the dc_bins subcarriers (removed before the correction). residual_db: RMS misfit
    of the model to the averaged reference, dB below the reference (quality of the fit).
    """

    gain_db: np.ndarray
    phase_rad: np.ndarray
    delay_s: np.ndarray
    correction: np.ndarray
    dc_offset: np.ndarray
    dc_bins: np.ndarray
    residual_db: float
    num_frames: int

    def apply(self, csi):
        """Calibrated copy of CSI frames (..., M, N), complex128."""
        out = np.array(csi, dtype=np.complex128)
        if np.any(self.dc_bins):
            out[..., self.dc_bins] -= self.dc_offset[:, None]
        out *= self.correction
        return out

    def summary(self):
        return (f"RX calibration from {self.num_frames} reference frames: gain "
                f"{np.ptp(self.gain_db):.2f} dB p-p, phase {math.degrees(np.ptp(self.phase_rad)):.1f} deg p-p, "
                f"delay {np.ptp(self.delay_s) * 1e12:.1f} ps p-p, model misfit {self.residual_db:.1f} dB")


def dc_subcarriers(subcarrier_offsets_hz):
    """The subcarriers next to DC (|Δf| ≤ half a spacing): where a DC offset lands."""
    offsets = np.asarray(subcarrier_offsets_hz, float)
    spacing = float(np.median(np.diff(offsets))) if offsets.size > 1 else 1.0
    return np.abs(offsets) <= 0.5 * spacing * (1.0 + 1e-9)


def calibrate_rx(reference_csi, subcarrier_offsets_hz, model=True):
    """Calibration from reference frames (R, M, N) on subcarriers at these offsets from the
    carrier (N,); phases are those at the carrier.

    Raises ValueError on an empty, non-finite or all-zero reference, naming the problem.
    """
    ref = np.asarray(reference_csi, dtype=np.complex128)
    if ref.ndim == 2:
        ref = ref[None]
    if ref.ndim != 3 or ref.shape[0] == 0:
        raise ValueError(f"rx_reference: expected frames (R, M, N), got shape {ref.shape}")
    if not np.all(np.isfinite(ref)):
        raise ValueError("rx_reference: the reference frames hold NaN or Inf")
    offsets = np.asarray(subcarrier_offsets_hz, float)
    num_frames, num_rx, num_sc = ref.shape
    if offsets.shape != (num_sc,):
        raise ValueError(f"rx_reference: {offsets.size} subcarrier offsets for {num_sc} subcarriers")
    dc = dc_subcarriers(offsets)
    use = ~dc if np.count_nonzero(~dc) >= 2 else np.ones(num_sc, bool)

    # Average the frames on the ratio to channel 0, which cancels s(f) frame by frame.
    anchor = ref[:, :1, :]
    if np.any(np.abs(anchor[:, :, use]) == 0):
        raise ValueError("rx_reference: channel 0 is zero on some subcarriers; no reference signal")
    ratio = np.mean(ref / np.where(np.abs(anchor) == 0, 1.0, anchor), axis=0)  # (M, N): β_m/β_0
    amp = np.abs(ratio)
    if np.any(amp[:, use] == 0):
        raise ValueError("rx_reference: a channel is zero; no reference signal on it")
    phase = np.unwrap(np.angle(ratio[:, use]), axis=1)  # relative chain delays are ps: smooth
    omega = 2.0 * np.pi * offsets[use]
    design = np.column_stack((np.ones(omega.size), -omega))
    coef, *_ = np.linalg.lstsq(design, phase.T, rcond=None)  # (2, M): φ_m - φ_0, δ_m - δ_0
    phase_rel = coef[0] - coef[0].mean()
    delay_rel = coef[1] - coef[1].mean()
    log_amp = np.log(amp[:, use]).mean(axis=1)
    log_amp -= log_amp.mean()
    fitted = np.exp(log_amp[:, None] + 1j * (phase_rel[:, None] - 2.0 * np.pi * np.outer(delay_rel, offsets)))
    # The same relative response, as the averaged data say it, on the channel mean's scale.
    common = np.exp(np.mean(np.log(amp), axis=0) + 1j * np.mean(np.unwrap(np.angle(ratio), axis=1), axis=0))
    measured = ratio / common
    misfit = measured[:, use] - fitted[:, use]
    residual_db = 10.0 * math.log10(max(np.mean(np.abs(misfit) ** 2) / np.mean(np.abs(fitted[:, use]) ** 2), 1e-30))

    # DC offset: what the reference holds there beyond the chain response (model only). The
    # reference seen through the fitted chains, β̄(f)·s(f), is equal on every channel; its
    # smooth amplitude and linear phase over the clean subcarriers give it at DC.
    dc_offset = np.zeros(num_rx, complex)
    if model and np.any(dc) and np.any(use):
        seen = (ref[:, :, use] / fitted[None, :, use]).mean(axis=1)  # (R, U)
        seen_phase = np.unwrap(np.angle(seen), axis=1)
        line = np.polyfit(offsets[use], seen_phase.T, 1)  # (2, R)
        level = np.abs(seen).mean(axis=1)  # (R,)
        at_dc = level[:, None] * np.exp(1j * (np.outer(line[0], offsets[dc]) + line[1][:, None]))  # (R, D)
        dc_offset = np.mean(ref[:, :, dc] - fitted[None, :, dc] * at_dc[:, None, :], axis=(0, 2))
    response = fitted if model else measured
    return RxCalibration(
        gain_db=20.0 * log_amp / math.log(10.0),
        phase_rad=np.angle(np.exp(1j * phase_rel)),
        delay_s=delay_rel,
        correction=1.0 / response,
        dc_offset=dc_offset,
        dc_bins=dc if model else np.zeros(num_sc, bool),
        residual_db=residual_db,
        num_frames=num_frames,
    )


def calibrate_survey(survey, model=True):
    """RxCalibration from a survey's rx_reference frames, or None when it has none."""
    frames = survey.reference_frames()
    if frames.size == 0:
        return None
    return calibrate_rx(np.asarray(survey.csi[frames]), survey.subcarrier_offsets_hz, model=model)


class CalibratedCsi:
    """A read-only view of a survey's CSI that calibrates the frames it is indexed with, so a
    survey of any size is corrected one pose group at a time."""

    def __init__(self, csi, calibration):
        self._csi = csi
        self._cal = calibration
        self.shape = csi.shape
        self.dtype = np.dtype(np.complex128)
        self.ndim = csi.ndim

    def __len__(self):
        return self.shape[0]

    def __getitem__(self, index):
        return self._cal.apply(self._csi[index])

    def __array__(self, dtype=None, copy=None):
        out = self._cal.apply(self._csi)
        return out if dtype is None else out.astype(dtype)


def calibrated_survey(survey, calibration):
    """The survey with its CSI seen through the calibration (the file is not touched)."""
    if calibration is None:
        return survey
    return replace(survey, csi=CalibratedCsi(survey.csi, calibration))
