#
# SPDX-License-Identifier: GPL-3.0-or-later
#
"""TX chain calibration from frames sounded with one TX element at a time (paper §3.3).

A frame sounded with element k alone, weight v (FORMATS.md: a frame whose
`thrumapper:tx_weights` has one non-zero entry), holds, once the RX chains are calibrated,

    H[m, n] = v · α_k(f_n) · (d_km(f_n) + echoes) · e^{−j2π f_n τ_sys} + noise,

with d_km = λ_n/(4π|t_k − r_m|) · e^{−j2π f_n |t_k − r_m|/c} the direct path, whose geometry
is known. Matching every frame with its element's direct path over the RX elements gives
α_k(f_n)·e^{−j2π f_n τ_sys} per subcarrier, plus what the echoes leave in it; the ratio to
element 0 cancels τ_sys and everything else common to the elements. As for the RX chains
(rx_calibration), only the chains' *relative* gains, phases and delays can be measured, and
only they matter: a factor common to every TX element scales the whole beam.

Why the TX chains matter: the survey's weights steer a null at the receiver, and chain
phase errors of 2° rms fill it to about −37 dB of the elements' direct paths, tens of dB above
the echoes of hidden walls (docs/mapping.md, "What the TX chains' errors cost"). The
correction c_k = 1/α_k at the carrier, multiplied into the weights, puts the null back
(`corrected_weights`). The radio applies it, so the survey records the nominal weights and,
as FORMATS.md's model says, α_k = 1 once the radio is calibrated.

The echoes are what limits the estimate where the arrays stand near walls: each element
sees them at its own phase relative to its direct path, so they do not cancel in the ratio,
and along a straight corridor the walls' echoes are the same at every pose, so averaging
poses does not remove them either (the office floor's corridor walls, 21 dB below the direct
path, leave 0.8° rms in the phases). So each element's echoes are fitted and removed first:
per pose, its direct path and up to 16 paths (spherical waves from the TX element's images,
placed one at a time and re-placed after each new one, RELAX-style, with Gauss-Newton on
their angle and delay) are fitted jointly by least squares, and what the paths explain is
subtracted. The relative responses of several poses are then combined by their median, so
that one pose whose fit went wrong does not move the result. On the office floor this
leaves 0.06° rms from one pose and 0.03° from four (docs/mapping.md, "The TX calibration").
"""

import math
from dataclasses import dataclass

import numpy as np

SPEED_OF_LIGHT_M_S = 299_792_458.0

#: A weight counts as "off" below this fraction of the largest one (a frame with one element on).
OFF_WEIGHT_FRACTION = 1e-9


@dataclass(eq=False)
class TxCalibration:
    """Relative TX chain responses and the correction that removes them from the weights.

    gain_db, phase_rad, delay_s: (K,) per TX element, relative to the elements' mean (mean of
    the gains in dB, of the phases and of the delays is zero); phases at the carrier.
    response: (K, N) the fitted relative response α_k(f_n). correction: (K,) complex,
    1/α_k(fc), the factor each element's weight is multiplied by. frames_per_element: (K,).
    residual_db: RMS misfit of the model to the measured relative responses, dB below them
    (what the echoes and the noise leave; a quality figure, not an error bound).
    """

    gain_db: np.ndarray
    phase_rad: np.ndarray
    delay_s: np.ndarray
    response: np.ndarray
    correction: np.ndarray
    frames_per_element: np.ndarray
    residual_db: float
    carrier_hz: float

    @property
    def num_tx(self):
        return self.gain_db.size

    def corrected_weights(self, weights):
        """The weights to send so that the radiated ones are `weights` (K,) complex."""
        w = np.asarray(weights, dtype=np.complex128).reshape(-1)
        if w.size != self.num_tx:
            raise ValueError(f"tx_weights: {w.size} weights for a calibration of {self.num_tx} TX elements")
        return w * self.correction

    def summary(self):
        return (f"TX calibration from {int(self.frames_per_element.sum())} single-element frames "
                f"({int(self.frames_per_element.min())}-{int(self.frames_per_element.max())} per element): "
                f"gain {np.ptp(self.gain_db):.2f} dB p-p, phase {math.degrees(np.ptp(self.phase_rad)):.1f} deg p-p, "
                f"delay {np.ptp(self.delay_s) * 1e12:.1f} ps p-p, model misfit {self.residual_db:.1f} dB")


def _single_elements(weights):
    """Per row of weights (F, K): the index of the one element it switches on, else -1."""
    w = np.abs(np.asarray(weights, dtype=np.complex128))
    if w.size == 0:
        return np.full(w.shape[0], -1)
    largest = w.max(axis=1)
    on = w > OFF_WEIGHT_FRACTION * largest[:, None]
    alone = np.all(np.isfinite(w), axis=1) & (largest > 0) & (np.count_nonzero(on, axis=1) == 1)
    return np.where(alone, np.argmax(on, axis=1), -1)


def single_element(weights):
    """The index of the one element a weight vector switches on, else -1."""
    return int(_single_elements(np.asarray(weights).reshape(1, -1))[0])


def single_element_frames(survey):
    """(frames, elements): the survey frames sounded with one TX element alone, ascending:
    a TX calibration. Empty on a radar of one TX element, whose every frame is sounded so."""
    frames = survey.survey_frames()
    if survey.num_tx < 2:
        return frames[:0], np.empty(0, dtype=int)
    elements = _single_elements(survey.frame_tx_weights[frames])
    keep = elements >= 0
    return frames[keep], elements[keep]


def element_direct_paths(tx_elements_m, rx_elements_m, frequencies_hz):
    """(K, M, N): the direct path from every TX element to every RX element, unit weight,
    without the system delay (FORMATS.md's near-field, wideband response; free-space
    spreading λ/(4πd), the wavelength's change over the band included)."""
    tx = np.asarray(tx_elements_m, float).reshape(-1, 2)
    rx = np.asarray(rx_elements_m, float).reshape(-1, 2)
    f = np.asarray(frequencies_hz, float).reshape(-1)
    dist = np.hypot(*(tx[:, None, :] - rx[None, :, :]).transpose(2, 0, 1))[:, :, None]  # (K, M, 1)
    wavelength = SPEED_OF_LIGHT_M_S / f[None, None, :]
    return wavelength / (4.0 * np.pi * dist) * np.exp(-2j * np.pi * dist / wavelength)


def _system_delay(direct, data, frequencies_hz, span_s=200e-9, step_s=0.05e-9):
    """τ_sys from the matched filter of every element's direct path (K, M, N) with the data
    (K, M, N): the peak of |Σ_kmn conj(d)·h·e^{+j2πfτ}| over [0, span), refined by a parabola."""
    c = np.einsum("kmn,kmn->n", direct.conj(), data)
    taus = np.arange(0.0, span_s, step_s)
    response = np.abs(np.exp(2j * np.pi * np.outer(taus, frequencies_hz)) @ c)
    i = int(np.argmax(response))
    if 0 < i < taus.size - 1:
        y0, y1, y2 = response[i - 1], response[i], response[i + 1]
        denom = y0 - 2 * y1 + y2
        return float(taus[i] + (0.5 * (y0 - y2) / denom * step_s if denom != 0 else 0.0))
    return float(taus[i])


class _EchoDictionary:
    """Paths at the RX array, searched as far-field waves u(θ, τ)[m, n] = e^{−j2πf_n(τ − r_m·e_θ/c)}
    on a coarse angle × delay grid, then refined as spherical waves from a point at the
    path's length c·(τ − τ_sys) in direction θ (a wall's echo comes from the TX element's
    image, which is that far: at 2 m the curvature over the array is 4°, enough to leave
    a per-cent of the echo unexplained)."""

    def __init__(self, rx_elements_m, frequencies_hz, max_delay_s, system_delay_s=0.0, min_delay_s=0.0):
        self.rx = np.asarray(rx_elements_m, float) - np.mean(rx_elements_m, axis=0)
        self.f = np.asarray(frequencies_hz, float)
        self.system_delay_s = float(system_delay_s)
        self._inv_f = 1.0 / self.f
        self.angles = np.radians(np.arange(0.0, 360.0, 2.0))
        self.min_delay_s = float(min_delay_s)
        self.delays = np.arange(self.min_delay_s, max_delay_s, 0.25e-9)
        self._steer = self._array(self.angles)  # (A, M, N)
        self._delay = np.exp(2j * np.pi * np.outer(self.f, self.delays))  # (N, D): conj of e^{−j2πfτ}

    def _array(self, angles):
        proj = np.cos(angles)[:, None] * self.rx[None, :, 0] + np.sin(angles)[:, None] * self.rx[None, :, 1]  # (A, M)
        return np.exp(2j * np.pi * proj[:, :, None] * self.f[None, None, :] / SPEED_OF_LIGHT_M_S)

    def spherical(self, angles, delays):
        """(A, D, M, N) unit-norm spherical-wave atoms."""
        length = np.maximum(SPEED_OF_LIGHT_M_S * (np.asarray(delays) - self.system_delay_s), 0.3)  # (D,)
        src = length[None, :, None] * np.stack((np.cos(angles), np.sin(angles)), axis=-1)[:, None, :]  # (A, D, 2)
        dist = np.linalg.norm(src[:, :, None, :] - self.rx[None, None, :, :], axis=-1)  # (A, D, M)
        extra = (dist - length[None, :, None]) / SPEED_OF_LIGHT_M_S + np.asarray(delays)[None, :, None]
        atoms = (length[None, :, None] / dist)[..., None] * np.exp(-2j * np.pi * extra[..., None] * self.f) / self.f
        return atoms / np.linalg.norm(atoms, axis=(2, 3), keepdims=True)

    def atom(self, angle, delay):
        """One unit-norm spherical-wave atom (M*N,), as spherical() makes them (called
        thousands of times a calibration: kept lean)."""
        length = max(SPEED_OF_LIGHT_M_S * (delay - self.system_delay_s), 0.3)
        dist = np.hypot(length * math.cos(angle) - self.rx[:, 0], length * math.sin(angle) - self.rx[:, 1])
        extra = (dist - length) / SPEED_OF_LIGHT_M_S + delay
        a = np.exp(np.outer(-2j * np.pi * extra, self.f))
        a *= (length / dist)[:, None]
        a *= self._inv_f
        a = a.ravel()
        return a / math.sqrt(np.vdot(a, a).real)

    def best(self, residual, others):
        """The (angle, delay) of the path that explains most of the residual (M, N), the
        part of the data orthogonal to the columns of `others` (orthonormal, (M*N, C))."""
        z = np.einsum("amn,mn->an", self._steer.conj(), residual)  # (A, N)
        score = np.abs(z @ self._delay)
        a, d = np.unravel_index(int(np.argmax(score)), score.shape)
        angle, delay = self.refine(residual, others, self.angles[a], self.delays[d])
        return self.newton(residual, others, angle, delay)

    def refine(self, residual, others, angle, delay, angle_step=math.radians(1.0), delay_step=0.125e-9, levels=2):
        """Zoom in around (angle, delay), scoring each candidate by what it adds to the fit
        of the other columns (orthogonal least squares: its part orthogonal to them): a
        path 4 mm long off leaves a tenth of its echo unexplained at 2.4 GHz, and a
        candidate scored by its plain correlation drifts toward what the direct path's fit
        took from the echo."""
        r = residual.ravel()
        for _ in range(levels):
            angles = angle + angle_step * np.arange(-4, 5) / 4.0
            delays = delay + delay_step * np.arange(-4, 5) / 4.0
            cands = self.spherical(angles, delays).reshape(angles.size * delays.size, -1).T  # (MN, C)
            perp = cands - others @ (others.conj().T @ cands)
            score = np.abs(perp.conj().T @ r) ** 2 / np.maximum(np.sum(np.abs(perp) ** 2, axis=0), 1e-30)
            a, d = np.unravel_index(int(np.argmax(score)), (angles.size, delays.size))
            angle, delay = angles[a], max(delays[d], self.min_delay_s)
            angle_step, delay_step = angle_step / 3.0, delay_step / 3.0
        return float(angle), float(delay)

    def newton(self, residual, others, angle, delay, iterations=4):
        """Gauss-Newton on (angle, delay) from a start within the path's main lobe, with the
        same criterion as refine (the candidate's part orthogonal to `others` fitted to the
        residual): three atoms an iteration instead of a grid's eighty."""
        r = residual.ravel()
        h_angle, h_delay = 1e-4, 1e-12
        others_h = others.conj().T

        def perp(angle_, delay_):
            a = self.atom(angle_, delay_)
            return a - others @ (others_h @ a)

        def cost(a_perp):
            return np.sum(np.abs(r) ** 2) - np.abs(np.vdot(a_perp, r)) ** 2 / max(np.vdot(a_perp, a_perp).real, 1e-30)

        a0 = perp(angle, delay)
        best = cost(a0)
        for _ in range(iterations):
            c = np.vdot(a0, r) / max(np.vdot(a0, a0).real, 1e-30)
            d_angle = (perp(angle + h_angle, delay) - a0) / h_angle
            d_delay = (perp(angle, delay + h_delay) - a0) / h_delay
            e = r - c * a0
            # unknowns: δc (re, im), δangle, δdelay (the last scaled to ns for conditioning)
            cols = np.column_stack((a0, 1j * a0, c * d_angle, c * d_delay * 1e-9))
            system = np.vstack((cols.real, cols.imag))
            step, *_ = np.linalg.lstsq(system, np.concatenate((e.real, e.imag)), rcond=None)
            move_angle, move_delay = step[2], max(step[3] * 1e-9, self.min_delay_s - delay)
            for _ in range(4):
                trial = perp(angle + move_angle, delay + move_delay)
                trial_cost = cost(trial)
                if trial_cost < best:
                    angle, delay, a0, best = angle + move_angle, delay + move_delay, trial, trial_cost
                    break
                move_angle, move_delay = move_angle / 2.0, move_delay / 2.0
            else:
                break
        return float(angle), float(delay)


def _orthonormal(columns):
    q, _ = np.linalg.qr(np.column_stack(columns))
    return q


def _remove_echoes(direct, data, frequencies_hz, rx_elements_m, max_echoes, max_delay_s, system_delay_s=0.0,
                   sweeps=1, min_delay_s=0.0):
    """The data (K, M, N) with each element's echoes fitted and subtracted: per element, the
    direct path (and its change with τ_sys, which the matched filter leaves a few ps off) and
    up to max_echoes paths found one at a time, each re-placed after every new one with the
    others held (RELAX), all fitted jointly by least squares; what the echoes explain is
    removed. The direct path itself and the noise stay."""
    if max_echoes <= 0:
        return data
    dictionary = _EchoDictionary(rx_elements_m, frequencies_hz, max_delay_s, system_delay_s, min_delay_s)
    slope = -2j * np.pi * (np.asarray(frequencies_hz, float) - np.mean(frequencies_hz))
    cleaned = np.empty_like(data)
    shape = data.shape[1:]
    for k in range(data.shape[0]):
        y = data[k].ravel()
        fixed = [direct[k].ravel(), (direct[k] * slope[None, :]).ravel()]
        params, atoms = [], []
        for count in range(max_echoes):
            q = _orthonormal(fixed + atoms)
            residual = y - q @ (q.conj().T @ y)
            params.append(dictionary.best(residual.reshape(shape), q))
            atoms.append(dictionary.atom(*params[-1]))
            for _ in range(sweeps if count else 0):
                for i in range(len(atoms)):
                    q = _orthonormal(fixed + atoms[:i] + atoms[i + 1:])
                    residual = y - q @ (q.conj().T @ y)
                    params[i] = dictionary.newton(residual.reshape(shape), q, *params[i])
                    atoms[i] = dictionary.atom(*params[i])
        basis = np.column_stack(fixed + atoms)
        coef, *_ = np.linalg.lstsq(basis, y, rcond=None)
        cleaned[k] = (y - basis[:, len(fixed):] @ coef[len(fixed):]).reshape(shape)
    return cleaned


def calibrate_tx(csi, elements, element_weights, tx_elements_m, rx_elements_m, carrier_hz, subcarrier_offsets_hz,
                 poses=None, max_echoes=16, max_echo_delay_s=60e-9):
    """Calibration from single-element frames.

    Per pose, each element's frames are averaged; its strongest max_echoes echoes (delays
    up to max_echo_delay_s past the system delay) are fitted with its direct path and
    removed (0: none, for frames without echoes: a TX combiner, an anechoic room); the
    poses' relative responses are combined by their median.

    csi: (R, M, N) frames, RX chains calibrated; elements: (R,) the element each frame
    sounded; element_weights: (R,) complex, its weight in that frame; geometry and
    subcarriers as in the survey; poses: (R,) labels of the place each frame was taken
    (default: one place). Every element needs at least one frame.

    Raises ValueError naming the problem: a wrong shape, NaN or Inf, an element without
    frames or out of range, a zero weight, or frames without signal.
    """
    h = np.asarray(csi, dtype=np.complex128)
    if h.ndim == 2:
        h = h[None]
    tx = np.asarray(tx_elements_m, float).reshape(-1, 2)
    rx = np.asarray(rx_elements_m, float).reshape(-1, 2)
    num_tx, num_rx = tx.shape[0], rx.shape[0]
    offsets = np.asarray(subcarrier_offsets_hz, float).reshape(-1)
    if h.ndim != 3 or h.shape[0] == 0 or h.shape[1:] != (num_rx, offsets.size):
        raise ValueError(f"tx calibration: expected frames (R, {num_rx}, {offsets.size}), got shape {h.shape}")
    elements = np.asarray(elements).reshape(-1)
    weights = np.asarray(element_weights, dtype=np.complex128).reshape(-1)
    if elements.shape != (h.shape[0],) or weights.shape != (h.shape[0],):
        raise ValueError(f"tx calibration: {elements.size} elements and {weights.size} weights for {h.shape[0]} frames")
    if not np.all(np.isfinite(h)):
        raise ValueError("tx calibration: the frames hold NaN or Inf")
    if not np.all(np.isfinite(weights)) or np.any(weights == 0):
        raise ValueError("tx calibration: every frame needs its element's non-zero, finite weight")
    if np.any((elements < 0) | (elements >= num_tx)):
        raise ValueError(f"tx calibration: element indices must be 0..{num_tx - 1}, got {sorted(set(elements.tolist()))}")
    counts = np.bincount(elements.astype(int), minlength=num_tx)
    if np.any(counts == 0):
        raise ValueError(f"tx calibration: no frame sounds TX element(s) {np.flatnonzero(counts == 0).tolist()}")
    if not math.isfinite(carrier_hz) or carrier_hz <= 0:
        raise ValueError(f"tx calibration: carrier must be a positive frequency, got {carrier_hz}")

    frequencies = carrier_hz + offsets
    direct = element_direct_paths(tx, rx, frequencies)  # (K, M, N)
    places = np.zeros(h.shape[0], int) if poses is None else np.unique(np.asarray(poses).reshape(-1),
                                                                          return_inverse=True)[1].reshape(-1)
    if places.size != h.shape[0]:
        raise ValueError(f"tx calibration: {places.size} pose labels for {h.shape[0]} frames")
    # An echo less than 0.3 m longer than the direct path would be the direct path to the
    # fit: none is looked for there (a wall that near the arrays cannot be told from it).
    dist = np.hypot(*(tx[:, None, :] - rx[None, :, :]).transpose(2, 0, 1))
    shortest_echo_s = (dist.max() + 0.3) / SPEED_OF_LIGHT_M_S
    log_amps, phases = [], []
    for place in np.unique(places):
        # Per pose: the frames of one element averaged, its echoes (which change from pose
        # to pose) removed there, and the relative response measured; then the median over
        # the poses, which a pose whose echoes were fitted badly does not move.
        here = places == place
        at = np.zeros((num_tx, num_rx, offsets.size), complex)
        n_at = np.bincount(elements[here].astype(int), minlength=num_tx)
        if np.any(n_at == 0):
            continue  # a pose where some element was not sounded measures no relative response
        np.add.at(at, elements[here].astype(int), h[here] / weights[here, None, None])
        at /= n_at[:, None, None]
        if max_echoes > 0:
            # The echoes' delays are fitted after the system delay, which the direct paths give.
            tau_sys = _system_delay(direct, at, frequencies)
            shift = np.exp(-2j * np.pi * frequencies * tau_sys)
            at = _remove_echoes(direct * shift, at, frequencies, rx, max_echoes,
                                tau_sys + max_echo_delay_s, tau_sys, min_delay_s=tau_sys + shortest_echo_s)
        # Matched to the element's direct path over the RX elements, per subcarrier: what is
        # left of its echoes enters weighted as the direct path is, the noise averages over M.
        matched = np.einsum("kmn,kmn->kn", direct.conj(), at) / np.einsum("kmn->kn", np.abs(direct) ** 2)
        if np.any(matched == 0):
            raise ValueError("tx calibration: an element's frames hold no signal on some subcarriers")
        ratio = matched / matched[:1]  # τ_sys and the common factor cancel
        log_amps.append(np.log(np.abs(ratio)))
        phases.append(np.unwrap(np.angle(ratio), axis=1))  # relative chain delays are ps: smooth
    if not phases:
        raise ValueError("tx calibration: no pose where every TX element was sounded")
    log_amp_all = np.median(np.array(log_amps), axis=0)  # (K, N)
    stack = np.array(phases)
    # Phases of different poses may differ by whole turns; the first pose's set the branch.
    stack -= 2.0 * np.pi * np.round((stack - stack[:1]) / (2.0 * np.pi))
    phase = np.median(stack, axis=0)

    omega = 2.0 * np.pi * offsets
    design = np.column_stack((np.ones(omega.size), -omega))
    coef, *_ = np.linalg.lstsq(design, phase.T, rcond=None)  # (2, K): φ_k − φ_0, δ_k − δ_0
    phase_rel = coef[0] - coef[0].mean()
    delay_rel = coef[1] - coef[1].mean()
    log_amp = log_amp_all.mean(axis=1)
    log_amp -= log_amp.mean()
    response = np.exp(log_amp[:, None] + 1j * (phase_rel[:, None] - 2.0 * np.pi * np.outer(delay_rel, offsets)))
    # The same relative response as the averaged data say it, per subcarrier.
    measured = np.exp(log_amp_all - log_amp_all.mean(axis=0) + 1j * (phase - phase.mean(axis=0)))
    misfit = measured - response
    residual_db = 10.0 * math.log10(max(np.mean(np.abs(misfit) ** 2) / np.mean(np.abs(response) ** 2), 1e-30))
    at_carrier = np.exp(log_amp + 1j * phase_rel)
    return TxCalibration(
        gain_db=20.0 * log_amp / math.log(10.0),
        phase_rad=np.angle(np.exp(1j * phase_rel)),
        delay_s=delay_rel,
        response=response,
        correction=1.0 / at_carrier,
        frames_per_element=counts,
        residual_db=residual_db,
        carrier_hz=float(carrier_hz),
    )


def calibrate_survey_tx(survey, rx_calibration=None):
    """TxCalibration from a survey's single-element frames (RX chains corrected by
    rx_calibration when given), or None when it has none."""
    frames, elements = single_element_frames(survey)
    if frames.size == 0:
        return None
    csi = np.asarray(survey.csi[frames], np.complex128)
    if rx_calibration is not None:
        csi = rx_calibration.apply(csi)
    weights = survey.frame_tx_weights[frames, elements]
    poses = np.nan_to_num(np.asarray(survey.poses, float)[frames], nan=0.0)
    places = np.unique(poses, axis=0, return_inverse=True)[1].reshape(-1)
    carriers = np.asarray(survey.center_frequencies_hz, float)[frames]
    if np.ptp(carriers) > 0:
        raise ValueError("tx calibration: the single-element frames are on more than one carrier")
    return calibrate_tx(csi, elements, weights, survey.tx_elements_m, survey.rx_elements_m, float(carriers[0]),
                        survey.subcarrier_offsets_hz, poses=places)


def calibration_json(calibration):
    """The calibration as a JSON-ready dict: what usrp_survey.grc's TX correction file holds."""
    return {
        "kind": "thrumapper_tx_calibration",
        "carrier_hz": calibration.carrier_hz,
        "gain_db": [float(v) for v in calibration.gain_db],
        "phase_deg": [math.degrees(float(v)) for v in calibration.phase_rad],
        "delay_ps": [float(v) * 1e12 for v in calibration.delay_s],
        "correction": [[float(c.real), float(c.imag)] for c in calibration.correction],
        "frames_per_element": [int(v) for v in calibration.frames_per_element],
        "residual_db": float(calibration.residual_db),
    }


def load_correction(path, num_tx=None):
    """The per-element correction (K,) complex from a file calibration_json wrote; each TX
    weight is multiplied by it before it is sent. Raises ValueError naming the problem."""
    import json

    try:
        with open(path, encoding="utf-8") as handle:
            data = json.load(handle)
    except OSError as err:
        raise ValueError(f"TX calibration {path}: cannot read it ({err.strerror})") from None
    except json.JSONDecodeError as err:
        raise ValueError(f"TX calibration {path}: not JSON ({err.msg} at line {err.lineno})") from None
    if not isinstance(data, dict) or data.get("kind") != "thrumapper_tx_calibration":
        raise ValueError(f"TX calibration {path}: not a TX calibration (\"kind\" must be "
                         "\"thrumapper_tx_calibration\"; thrumapper-beam --tx-calibration --save writes one)")
    pairs = data.get("correction")
    try:
        correction = np.array([complex(float(re), float(im)) for re, im in pairs])
    except (TypeError, ValueError):
        raise ValueError(f"TX calibration {path}: \"correction\" must be a list of [re, im] pairs") from None
    if correction.size == 0 or not np.all(np.isfinite(correction)) or np.any(correction == 0):
        raise ValueError(f"TX calibration {path}: \"correction\" must hold finite, non-zero values")
    if num_tx is not None and correction.size != num_tx:
        raise ValueError(f"TX calibration {path}: {correction.size} corrections for {num_tx} TX elements")
    return correction


def null_depth_db(weights, tx_elements_m, rx_elements_m, frequencies_hz, chain_gains=None):
    """Energy of the direct path the weights radiate at the RX elements, over what the same
    weights' magnitudes would give with every element in phase (dB; the null's depth).
    chain_gains (K,) or (K, N): the TX chains' responses the weights go through (default 1)."""
    d = element_direct_paths(tx_elements_m, rx_elements_m, frequencies_hz)  # (K, M, N)
    w = np.asarray(weights, dtype=np.complex128).reshape(-1, 1)
    if chain_gains is not None:
        g = np.asarray(chain_gains, dtype=np.complex128)
        w = w * (g if g.ndim == 2 else g[:, None])
    field = np.einsum("kn,kmn->mn", w, d)
    bound = np.einsum("kn,kmn->mn", np.abs(w), np.abs(d))
    return 10.0 * math.log10(max(np.sum(np.abs(field) ** 2), 1e-300) / np.sum(bound ** 2))
