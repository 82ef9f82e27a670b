#
# SPDX-License-Identifier: GPL-3.0-or-later
#
"""JADE over a CSI survey: the code behind thrumapper-jade, shared with the other tools.

A survey's frames are grouped by pose (repeated soundings from one place stack their
snapshots), each group goes through the C++ `jade` core, and the delays come out as
FORMATS.md defines them: TX-centre to RX-centre, the system delay removed.
"""

import math
from dataclasses import dataclass

import numpy as np

from . import thrumapper_python as _core
from . import tx_calibration
from .survey import group_frames_by_pose

@dataclass
class JadeSettings:
    """Grids and estimator settings shared by the tools."""

    num_angles: int = 360
    num_delays: int = 240
    delay_min_s: float = 0.0
    delay_max_s: float = 60e-9
    max_paths: int = 4
    smoothing_window: int = 0
    #: successive-cancellation stages (1: estimate once); each stage reports up to max_paths
    stages: int = 1
    #: cancel the direct TX->RX path with its exact near-field response before JADE (its
    #: far-field image is a spray of weak unphysical paths below ~3 ns)
    cancel_direct_path: bool = True

    def check(self):
        if self.num_angles < 3:
            raise ValueError(f"num_angles: at least 3 angles are needed, got {self.num_angles}")
        if self.num_delays < 2:
            raise ValueError(f"num_delays: at least 2 delays are needed, got {self.num_delays}")
        if not (math.isfinite(self.delay_min_s) and math.isfinite(self.delay_max_s)) or \
                self.delay_max_s <= self.delay_min_s:
            raise ValueError(f"delay span: delay_max_s ({self.delay_max_s}) must be above "
                             f"delay_min_s ({self.delay_min_s})")
        if not 1 <= self.max_paths <= 64:
            raise ValueError(f"max_paths: expected 1 to 64, got {self.max_paths}")
        if not 1 <= self.stages <= 16:
            raise ValueError(f"stages: expected 1 to 16, got {self.stages}")


def radar_from_survey(survey, carrier_hz=None, tx_weights=None):
    """The radar description of a survey (its element positions and subcarriers)."""
    fc = float(survey.center_frequencies_hz[0] if carrier_hz is None else carrier_hz)
    weights = survey.tx_weights if tx_weights is None else tx_weights
    return _core.radar_description.make(
        np.asarray(survey.tx_elements_m, float), np.asarray(survey.rx_elements_m, float), fc,
        [float(f) for f in survey.subcarrier_offsets_hz], [complex(w) for w in weights])


def make_estimator(radar, settings):
    settings.check()
    est = _core.jade(radar, _core.jade.full_circle_grid(settings.num_angles),
                     _core.jade.linear_grid(settings.delay_min_s, settings.delay_max_s,
                                            settings.num_delays),
                     settings.smoothing_window, settings.max_paths)
    est.set_stages(settings.stages)
    return est


#: Share of a frame's energy the direct path must hold for the system delay to be measured
#: on it. Below this, walls would pull the matched filter (with the TX null steered at the
#: receiver the direct path is tens of dB down): the tools then ask for the delay instead.
DIRECT_PATH_MIN_ENERGY_SHARE = 0.5


def estimate_system_delay(survey, groups, max_groups=5, oversample=64):
    """τ_sys from the direct TX→RX path, whose geometry is known.

    The direct path's response is known exactly up to a complex gain and τ_sys: the
    near-field, wideband coupling Σ_k w_k e^{-j2π f_n (|t_k - r_m|/c + τ_sys)} / |t_k - r_m|
    with the frame's TX weights. The matched filter over τ_sys is then an inverse DFT over
    the subcarriers, evaluated on a fine grid over one period 1/Δf (τ_sys is only defined
    modulo the subcarrier spacing's ambiguity) and refined by a parabola through the peak.
    The median over the first pose groups is returned, in [0, 1/Δf).

    A survey with a TX calibration (frames sounded with one element alone, whose direct
    path is not nulled) is measured on those frames instead, one group per element.

    Raises ValueError when the direct path holds less than DIRECT_PATH_MIN_ENERGY_SHARE of
    the frames' energy (a nulled TX, or no frames).
    """
    single, elements = tx_calibration.single_element_frames(survey)
    if single.size:
        groups = [(single[elements == k], None) for k in np.unique(elements)]
        max_groups = max(max_groups, len(groups))
    if not groups:
        raise ValueError("system delay: the survey has no survey frames")
    offsets = np.asarray(survey.subcarrier_offsets_hz, float)
    spacing = np.diff(offsets)
    if np.max(np.abs(spacing - spacing.mean())) > 1e-6 * spacing.mean():
        raise ValueError("system delay: needs uniformly spaced subcarriers")
    df = spacing.mean()
    period_s = 1.0 / df
    n_sc = offsets.size
    size = oversample * n_sc
    estimates, shares = [], []
    for frames, _pose in groups[:max_groups]:
        weights = survey.frame_tx_weights[frames[0]]
        radar = radar_from_survey(survey, survey.center_frequencies_hz[frames[0]], weights)
        r0 = np.asarray(_core.direct_path_response(radar, [complex(w) for w in weights], 0.0))
        r0 = r0.reshape(radar.num_rx, n_sc)
        h = np.asarray(survey.csi[frames], np.complex128)
        # c_n = Σ_m conj(r0[m, n]) h[m, n]; the carrier's phase factor has modulus one
        c = np.einsum("mn,fmn->fn", r0.conj(), h)
        # J(τ) = Σ_f |Σ_n c_n e^{+j2π n Δf τ}|² on the grid τ_k = k / (size Δf)
        J = (np.abs(np.fft.ifft(c, size, axis=1)) ** 2).sum(0) * size ** 2
        k = int(np.argmax(J))
        y0, y1, y2 = J[k - 1], J[k], J[(k + 1) % size]
        denom = y0 - 2 * y1 + y2
        frac = 0.5 * (y0 - y2) / denom if denom != 0 else 0.0
        tau = ((k + frac) / size * period_s) % period_s
        # the offsets' start shifts the DFT's phase reference, not |J|: τ is unaffected
        share = J[k] / (np.sum(np.abs(r0) ** 2) * np.sum(np.abs(h) ** 2))
        shares.append(share)
        if share >= DIRECT_PATH_MIN_ENERGY_SHARE:
            estimates.append(tau)
    if not estimates:
        raise ValueError(
            "system delay: the direct TX->RX path holds only "
            f"{100 * max(shares):.0f}% of the energy in the first {len(shares)} pose groups "
            f"(at least {100 * DIRECT_PATH_MIN_ENERGY_SHARE:.0f}% is needed to measure the delay "
            "on it; is the TX null steered at the receiver?). Give the delay with "
            "--system-delay-s, or record it as thrumapper:system_delay_s (a calibration "
            "frame without the null measures it)")
    ref = estimates[0]
    unwrapped = [ref + ((e - ref + period_s / 2) % period_s - period_s / 2) for e in estimates]
    return float(np.median(unwrapped) % period_s)


def run_survey(survey, settings=None, system_delay_s=None, progress=None, keep_csi=False, pose_groups=None):
    """JADE on every pose group of a survey (or on the groups a slice `pose_groups` picks).

    Yields one dict per group: {"frames": [...], "pose": [x, y, heading],
    "paths": [{"aoa_deg", "delay_s", "power", "stage"}, ...], "model_order": int,
    "spectrum_db": (A, D) array}. The system delay comes from the argument, else the survey,
    else the direct path. `progress` is an optional tqdm-like wrapper for the group list.
    keep_csi adds "csi": the frames as JADE saw them (direct path cancelled) and "tx_weights".
    """
    settings = settings or JadeSettings()
    groups = group_frames_by_pose(survey)
    if system_delay_s is None:
        system_delay_s = survey.system_delay_s
    if system_delay_s is None:
        system_delay_s = estimate_system_delay(survey, groups)
    if pose_groups is not None:
        groups = groups[pose_groups]
    estimators = {}
    projectors = {}
    iterable = progress(groups) if progress else groups
    for frames, pose in iterable:
        fc = float(survey.center_frequencies_hz[frames[0]])
        if fc not in estimators:
            est = make_estimator(radar_from_survey(survey, fc), settings)
            est.set_system_delay(system_delay_s)
            estimators[fc] = est
        est = estimators[fc]
        csi = np.asarray(survey.csi[frames], np.complex128)
        if settings.cancel_direct_path:
            weights = tuple(complex(w) for w in survey.frame_tx_weights[frames[0]])
            key = (fc, weights)
            if key not in projectors:
                proj = _core.path_projector(est.radar)
                proj.set_system_delay(system_delay_s)
                proj.set_direct_path(True, list(weights))
                projectors[key] = proj
            csi = projectors[key].apply(csi)
        paths = est.estimate(csi)
        extra = {"csi": csi, "tx_weights": np.asarray(survey.frame_tx_weights[frames[0]], complex)} if keep_csi else {}
        yield {**extra,
            "frames": [int(f) for f in frames],
            "pose": [float(v) for v in pose],
            "paths": [{"aoa_deg": p.aoa_deg % 360.0, "delay_s": p.delay_s, "power": p.power,
                       "stage": p.stage} for p in paths],
            "model_order": est.model_order,
            "system_delay_s": system_delay_s,
            "spectrum_db": np.array(est.spectrum_db),
            "angles_deg": np.degrees(est.angle_grid),
            "delays_s": np.asarray(est.delay_grid),
        }


def plot_surface(result, png_path, title=None, truth=None):
    """Write the angle×delay surface of one group's result as a PNG (matplotlib)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    s = result["spectrum_db"]
    angles = result["angles_deg"]
    delays_ns = result["delays_s"] * 1e9
    fig, ax = plt.subplots(figsize=(8, 5), dpi=110)
    mesh = ax.pcolormesh(delays_ns, angles, s, shading="auto", cmap="viridis")
    fig.colorbar(mesh, ax=ax, label="MUSIC pseudo-spectrum (dB)")
    for i, p in enumerate(result["paths"]):
        ax.plot(p["delay_s"] * 1e9, p["aoa_deg"], "r+", ms=14, mew=2,
                label="found" if i == 0 else None)
    for i, t in enumerate(truth or []):
        ax.plot(t["delay_s"] * 1e9, t["aoa_deg"], "wo", mfc="none", ms=12, mew=1.5,
                label="geometry" if i == 0 else None)
    ax.set_xlabel("delay TX→RX centre (ns, system delay removed)")
    ax.set_ylabel("angle of arrival (deg, CCW from robot +x)")
    pose = result["pose"]
    ax.set_title(title or f"JADE surface, frames {result['frames'][0]}–{result['frames'][-1]}, "
                 f"pose ({pose[0]:.2f}, {pose[1]:.2f}, {math.degrees(pose[2]):.1f}°)")
    if result["paths"] or truth:
        ax.legend(loc="upper right")
    fig.tight_layout()
    fig.savefig(png_path)
    plt.close(fig)
