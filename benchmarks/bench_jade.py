#!/usr/bin/python3
# SPDX-License-Identifier: GPL-3.0-or-later
"""JADE speed: spectra (with peaks) per second, C++ core vs two numpy references.

All three run in this process, on the same frames, on one core (BLAS threads pinned to 1):

* core       - thrumapper.jade.estimate: Gram-matrix subspace, separable spectrum (delay
               transform + one complex GEMM), grid peaks refined by Newton, amplitudes.
* numpy sep. - the same separable algorithm in numpy (thin SVD of the smoothed data, the
               delay transform and the angle GEMM), grid peaks without refinement.
* plain grid - the textbook way: the M·L×M·L covariance, its eigendecomposition, and
               uᴴ E_n E_nᴴ u evaluated for every grid point (vectorised per angle block).
               It is too slow to run on the whole grid at every N; it runs on a slice of
               the angles and is scaled to the whole grid (its cost is linear in the points).

It also times a full successive-cancellation update (up to 4 stages) against one stage.

Usage: benchmarks/bench_jade.py [--seconds S] [--markdown]
"""
import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("MKL_NUM_THREADS", "1")

import argparse  # noqa: E402
import math  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402

from gnuradio import thrumapper  # noqa: E402

NUM_ANGLES, NUM_DELAYS = 360, 200


def frame(radar, rng):
    paths = [(243.4, 5.22e-9, 1.0), (261.2, 15.2e-9, 0.1), (40.0, 9.0e-9, 0.3)]
    h = sum(g * np.asarray(thrumapper.space_time_manifold(radar, math.radians(a), d))
            for a, d, g in paths)
    n = radar.num_rx * radar.num_subcarriers
    h = h + 0.05 * (rng.standard_normal(n) + 1j * rng.standard_normal(n))
    return h.reshape(radar.num_rx, radar.num_subcarriers)


def rate(fn, seconds):
    fn()  # warm up
    count, start = 0, time.perf_counter()
    while True:
        fn()
        count += 1
        elapsed = time.perf_counter() - start
        if elapsed >= seconds and count >= 3:
            return count / elapsed


class NumpySeparable:
    def __init__(self, radar, angles, delays, L, order=3):
        self.M, self.N, self.L, self.order = radar.num_rx, radar.num_subcarriers, L, order
        rx = np.asarray(radar.rx_elements_m)
        rx = rx - rx.mean(0)
        k = 2 * np.pi * radar.carrier_hz / thrumapper.speed_of_light_m_s
        self.Ah = np.exp(-1j * k * (np.cos(angles)[:, None] * rx[:, 0] + np.sin(angles)[:, None] * rx[:, 1]))
        df = radar.subcarrier_spacing_hz
        self.Gc = np.exp(2j * np.pi * df * np.outer(np.arange(L), delays))
        self.idx = np.arange(L)[:, None] + np.arange(self.N - L + 1)[None, :]

    def __call__(self, H):
        Y = H[:, self.idx].reshape(self.M * self.L, -1)  # (M·L) × S Hankel stack
        U, s, _ = np.linalg.svd(Y, full_matrices=False)
        E = U[:, :self.order]
        B = E.T.reshape(self.order, self.M, self.L)  # per vector: M × L
        D = B @ self.Gc  # order × M × D: the delay transform
        Z = np.einsum("am,kmd->kad", self.Ah, D, optimize=True)  # the angle GEMM
        fit = (np.abs(Z) ** 2).sum(0) / (self.M * self.L)
        spec = -10 * np.log10(np.maximum(1 - fit, 1e-6))
        # grid peaks: local maxima over the 8 neighbours, angles wrapping
        p = np.pad(spec, ((1, 1), (1, 1)), mode="wrap")
        c = p[1:-1, 1:-1]
        mask = np.ones_like(c, bool)
        for da in (-1, 0, 1):
            for dd in (-1, 0, 1):
                if da or dd:
                    mask &= c >= p[1 + da:p.shape[0] - 1 + da, 1 + dd:p.shape[1] - 1 + dd]
        idx = np.argsort(spec[mask])[::-1][: self.order]
        return np.argwhere(mask)[idx]


class PlainGrid:
    """Noise-subspace MUSIC, point by point over the grid (vectorised per block of angles)."""

    def __init__(self, radar, angles, delays, L, order=3):
        self.radar, self.angles, self.delays, self.L, self.order = radar, angles, delays, L, order
        self.M, self.N = radar.num_rx, radar.num_subcarriers
        self.idx = np.arange(L)[:, None] + np.arange(self.N - L + 1)[None, :]
        rx = np.asarray(radar.rx_elements_m)
        self.rx = rx - rx.mean(0)
        self.k = 2 * np.pi * radar.carrier_hz / thrumapper.speed_of_light_m_s
        self.df = radar.subcarrier_spacing_hz

    def __call__(self, H, angle_slice):
        Y = H[:, self.idx].reshape(self.M * self.L, -1)
        R = Y @ Y.conj().T
        w, V = np.linalg.eigh(R)
        En = V[:, : self.M * self.L - self.order]
        g = np.exp(-2j * np.pi * self.df * np.outer(np.arange(self.L), self.delays))  # L × D
        chosen = self.angles[angle_slice]
        out = np.empty((len(chosen), len(self.delays)))
        for i, th in enumerate(chosen):
            a = np.exp(1j * self.k * (self.rx[:, 0] * math.cos(th) + self.rx[:, 1] * math.sin(th)))
            U = (a[:, None, None] * g[None, :, :]).reshape(self.M * self.L, -1)  # u for every delay
            den = (np.abs(En.conj().T @ U) ** 2).sum(0)
            out[i] = 10 * np.log10((self.M * self.L) / np.maximum(den, 1e-30))
        return out


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seconds", type=float, default=2.0, help="time per measurement (default 2)")
    ap.add_argument("--markdown", action="store_true", help="print a Markdown table for the docs")
    args = ap.parse_args()
    rng = np.random.default_rng(1)
    angles = np.asarray(thrumapper.jade.full_circle_grid(NUM_ANGLES))
    delays = np.asarray(thrumapper.jade.linear_grid(0, 40e-9, NUM_DELAYS))
    rows = []
    for N in (64, 128, 256):
        radar = thrumapper.radar_description.make_uca_pair(subcarriers=N)
        est = thrumapper.jade(radar, list(angles), list(delays), 0, 4)
        L = est.smoothing_window
        H = frame(radar, rng)
        core = rate(lambda: est.estimate(H), args.seconds)
        sep = NumpySeparable(radar, angles, delays, L)
        numpy_sep = rate(lambda: sep(H), args.seconds)
        plain = PlainGrid(radar, angles, delays, L)
        part = slice(0, 12)
        t0 = time.perf_counter()
        plain(H, part)
        plain_rate = 1.0 / ((time.perf_counter() - t0) * NUM_ANGLES / 12)
        rows.append((N, L, core, numpy_sep, plain_rate))
    # successive cancellation: a full update of 4 stages against the one-stage estimate, on a
    # frame with a corridor wall, clutter and a hidden wall 30 dB down
    radar = thrumapper.radar_description.make_uca_pair(subcarriers=128)
    h = sum(g * np.asarray(thrumapper.space_time_manifold(radar, math.radians(a), d))
            for a, d, g in [(243.4, 5.22e-9, 1.0), (120.0, 8e-9, 0.3), (30.0, 11e-9, 0.2),
                            (262.0, 15.2e-9, 10 ** -1.5)])
    h = (h + 1e-3 * (rng.standard_normal(h.size) + 1j * rng.standard_normal(h.size))).reshape(8, 128)
    one = thrumapper.jade(radar, list(angles), list(delays), 0, 3)
    four = thrumapper.jade(radar, list(angles), list(delays), 0, 3)
    four.set_stages(4)
    stage_rates = (rate(lambda: one.estimate(h), args.seconds), rate(lambda: four.estimate(h), args.seconds))
    head = ("N", "L", "core /s", "numpy separable /s", "plain grid /s", "core ÷ numpy sep.", "core ÷ plain")
    if args.markdown:
        print("| " + " | ".join(head) + " |")
        print("|" + "---|" * len(head))
        for N, L, c, s, p in rows:
            print(f"| {N} | {L} | {c:.0f} | {s:.0f} | {p:.3f} | {c / s:.1f}× | {c / p:.0f}× |")
        print()
        print("| N = 128, 4 paths | updates /s |")
        print("|---|---|")
        print(f"| one stage | {stage_rates[0]:.0f} |")
        print(f"| successive cancellation, up to 4 stages | {stage_rates[1]:.0f} |")
    else:
        print(f"M = 8, grid {NUM_ANGLES} angles x {NUM_DELAYS} delays, one core")
        print("{:>4} {:>4} {:>10} {:>19} {:>14} {:>18} {:>13}".format(*head))
        for N, L, c, s, p in rows:
            print(f"{N:>4} {L:>4} {c:>10.0f} {s:>19.0f} {p:>14.3f} {c / s:>17.1f}x {c / p:>12.0f}x")
        print(f"\nN = 128, 4 paths: one stage {stage_rates[0]:.0f} /s, "
              f"successive cancellation up to 4 stages {stage_rates[1]:.0f} updates/s "
              f"({stage_rates[0] / stage_rates[1]:.1f}x the time)")


if __name__ == "__main__":
    main()
