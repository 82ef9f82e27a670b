#!/usr/bin/python3
# SPDX-License-Identifier: GPL-3.0-or-later
"""Receive-chain speed: samples per second per channel, our blocks vs GNU Radio's OFDM path.

All flowgraphs run in this process on the same bursts: M = 8 channels of the default
sounding (120 MS/s, FFT 256, 128 subcarriers, frames of 1600 samples) through a synthetic
multipath channel with noise, read from memory (vector sources) into null sinks.

* estimator   - thrumapper.ofdm_channel_estimator: preamble timing (joint over the channels),
                FFT of the 4 estimation windows of every frame, least-squares CSI of 8×128.
* calibrator  - thrumapper.channel_calibrator with non-trivial coefficients: DC removal and
                the gain/phase/fractional-delay FIR (256 taps, overlap-save) on every sample.
* gr-digital  - GNU Radio's own OFDM path, per channel: keep_m_in_n (the same 4 windows of
                every frame, at their known positions: no timing search) → stream_to_vector
                → fft.fft_vcc → digital.ofdm_chanest_vcvc (2 sync symbols + 2 data symbols).

Speed is reported per CPU-second (process time of all threads: fair between one block and
a flowgraph of 32, and stable on a shared machine), with the wall-clock rate beside it.

Usage: benchmarks/bench_radio.py [--frames F] [--repeats R] [--markdown]
"""
import argparse
import time

import numpy as np
from gnuradio import blocks, digital, fft, gr

from gnuradio import thrumapper


def bursts(sounding, frames, seed=0):
    """(M, frames·P) complex64: every RX element hears Σ_k g_km·x_k over three paths + noise."""
    rng = np.random.default_rng(seed)
    K, M = sounding.num_tx, sounding.num_rx
    x = np.tile(sounding.frame([]), (1, frames))
    y = np.zeros((M, x.shape[1]), complex)
    for delay, scale in ((3, 1.0), (9, 0.3), (17, 0.1)):
        g = (rng.standard_normal((K, M)) + 1j * rng.standard_normal((K, M))) * scale
        shifted = np.concatenate((np.zeros((K, delay)), x[:, :-delay]), axis=1)
        y += np.einsum("km,kt->mt", g, shifted)
    y += 0.01 * (rng.standard_normal(y.shape) + 1j * rng.standard_normal(y.shape))
    return y.astype(np.complex64)


def timed(build, samples_per_channel, repeats):
    """Best (samples per CPU-second, samples per wall-second) per channel over `repeats` runs.

    CPU time (process_time: every thread of the process) is the measure that holds on a
    shared machine and compares a one-thread block fairly with a many-block flowgraph."""
    best_cpu = best_wall = 0.0
    for _ in range(repeats):
        tb = build()
        wall, cpu = time.perf_counter(), time.process_time()
        tb.run()
        cpu = time.process_time() - cpu
        wall = time.perf_counter() - wall
        best_cpu = max(best_cpu, samples_per_channel / cpu)
        best_wall = max(best_wall, samples_per_channel / wall)
    return best_cpu, best_wall


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--frames", type=int, default=400, help="frames per run (default 400)")
    parser.add_argument("--repeats", type=int, default=3, help="runs per flowgraph; the best counts")
    parser.add_argument("--markdown", action="store_true", help="print a Markdown table")
    args = parser.parse_args()

    radar = thrumapper.radar_description.make_uca_pair()
    sounding = thrumapper.ofdm_sounding.make(radar)
    M, N, F, P = sounding.num_rx, sounding.num_subcarriers, sounding.fft_len, sounding.frame_len
    J = sounding.num_symbols
    data = bursts(sounding, args.frames)
    samples = data.shape[1]
    streams = [data[m] for m in range(M)]

    def sources(tb):
        return [blocks.vector_source_c(s, False) for s in streams]

    def build_estimator():
        tb = gr.top_block()
        est = thrumapper.ofdm_channel_estimator(sounding)
        for m, src in enumerate(sources(tb)):
            tb.connect(src, (est, m))
        tb.connect(est, blocks.null_sink(gr.sizeof_gr_complex * M * N))
        return tb

    coefficients = thrumapper.calibration_coefficients.identity(M)
    coefficients.gain_db = list(np.linspace(-1, 1, M))
    coefficients.phase_rad = list(np.linspace(0, 3, M))
    coefficients.delay_s = list(np.linspace(-2e-10, 2e-10, M))
    coefficients.dc = [0.01 + 0.0j] * M

    def build_calibrator():
        tb = gr.top_block()
        cal = thrumapper.channel_calibrator(sounding, "reference", 0, 0, False)
        cal.set_coefficients(coefficients)
        for m, src in enumerate(sources(tb)):
            tb.connect(src, (cal, m), blocks.null_sink(gr.sizeof_gr_complex))
        return tb

    # GNU Radio's path: the pilot symbol on the FFT grid (fft_vcc's shifted order)
    pilots = np.zeros(F, complex)
    pilots[np.asarray(sounding.subcarrier_bins)] = sounding.pilots
    sync = list(np.fft.fftshift(pilots))
    first_window = sounding.window_start(0, 0) + 3  # the channel's 3-sample delay, known

    def build_gr():
        tb = gr.top_block()
        for src in sources(tb):
            keep = blocks.keep_m_in_n(gr.sizeof_gr_complex, J * F, P, first_window)
            s2v = blocks.stream_to_vector(gr.sizeof_gr_complex, F)
            spectrum = fft.fft_vcc(F, True, [], True, 1)
            chanest = digital.ofdm_chanest_vcvc(sync, sync, J - 2, 0, 0, False)
            tb.connect(src, keep, s2v, spectrum, chanest, blocks.null_sink(gr.sizeof_gr_complex * F))
        return tb

    rates = {
        "ofdm_channel_estimator": timed(build_estimator, samples, args.repeats),
        "channel_calibrator": timed(build_calibrator, samples, args.repeats),
        "gr-digital fft_vcc + ofdm_chanest_vcvc": timed(build_gr, samples, args.repeats),
    }
    reference = rates["gr-digital fft_vcc + ofdm_chanest_vcvc"][0]
    rows = [(name, cpu / 1e6, cpu / reference, wall / 1e6) for name, (cpu, wall) in rates.items()]
    header = (f"{M} channels, {args.frames} frames of {P} samples ({samples} samples per channel), "
              f"best of {args.repeats}; per CPU-second (all threads) and per wall-second")
    if args.markdown:
        print(header + "\n")
        print("| flowgraph | MS/s per channel per CPU-second | vs gr-digital | MS/s per channel (wall) |")
        print("|---|---:|---:|---:|")
        for name, cpu, ratio, wall in rows:
            print(f"| {name} | {cpu:.1f} | {ratio:.2f}× | {wall:.1f} |")
    else:
        print(header)
        for name, cpu, ratio, wall in rows:
            print(f"{name:40s} {cpu:8.1f} MS/s/channel per CPU-s   {ratio:6.2f}x gr-digital   {wall:8.1f} MS/s/channel wall")


if __name__ == "__main__":
    main()
