#
# SPDX-License-Identifier: GPL-3.0-or-later
#
"""The simulated building at sample level: K TX streams in, M RX streams out.

The channel is building_sim's per-element channel H[k, m, f] (channel_matrix_at_pose) at the
absolute frequency of every FFT bin of the sounding waveform, times the scene's chain
impairments (TX α_k(f), RX β_m(f), system delay τ_sys), turned into impulse responses at the
sample rate by an inverse FFT and applied by overlap-save convolution; the scene's DC offset
and noise are added. docs/radio-chain.md explains why this reproduces the CSI-level
simulation exactly on the sounding's periodic training slots.
"""

import math

import numpy as np
import pmt
from gnuradio import gr

from . import building_sim as _sim
from . import scene as _scene
from .survey_blocks import pose_from_pmt

KEY_POSE = pmt.intern("pose")
KEY_FRAME_TYPE = pmt.intern("frame_type")
KEY_RX_TIME = pmt.intern("rx_time")
KEY_RX_FREQ = pmt.intern("rx_freq")
KEY_TX_TIME = pmt.intern("tx_time")
POSE_PORT = pmt.intern("pose")
# Inputs processed per convolution block.
_CHUNK = 8192


def _check_radar(scene, sounding):
    """The scene's radar and the sounding's must be the same radar; ValueError otherwise."""
    radar = sounding.radar
    sc = scene.radar
    checks = (
        ("tx_elements_m", np.asarray(radar.tx_elements_m), sc.tx_elements_m, 1e-9),
        ("rx_elements_m", np.asarray(radar.rx_elements_m), sc.rx_elements_m, 1e-9),
        ("subcarrier_offsets_hz", np.asarray(radar.subcarrier_offsets_hz), sc.subcarrier_offsets_hz, 1e-3),
        ("carrier_hz", np.array([radar.carrier_hz]), np.array([sc.carrier_hz]), 1e-3),
    )
    for name, mine, theirs, tol in checks:
        if mine.shape != theirs.shape or not np.allclose(mine, theirs, rtol=0, atol=tol):
            raise ValueError(f"building_channel: the sounding's radar and the scene's radar differ in {name}")


class building_channel(gr.basic_block):
    """K TX streams through the simulated building to M RX streams (sample level).

    scene: a Scene or a scene file. sounding: the ofdm_sounding the TX streams carry (sample
    rate, FFT size, LO). The pose: the "pose" message port (a dict with "pose" or x, y,
    heading, or an f64vector) overrides the schedule; otherwise `pose` if given, else the
    scene's trajectory, pose i for samples_per_pose output samples each (after the reference
    samples; 0: the first pose throughout).

    reference_samples: the first samples carry the split reference instead of the building
    (FORMATS.md rx_reference: TX element 0's signal, amplitude rx_reference_amplitude and
    delay τ_sys, split equally into every RX chain), tagged frame_type rx_reference; then
    frame_type survey. impairments: apply the scene's chain gains, phases, delays, system
    delay and DC offset. noise: add the scene's noise, scaled so that the CSI estimated from
    num_symbols windows has the scene's noise power per CSI sample.

    Output sample n corresponds to input sample n (the channel's pre-cursor is applied with
    a lookahead of fft_len/8 samples, so the stream ends that much early). Tags out: "pose"
    (f64vector, true pose) whenever it changes, "frame_type", "rx_freq" (the LO) at 0, and
    "rx_time" from the first "tx_time" tag seen on input 0.
    """

    def __init__(self, scene, sounding, pose=None, samples_per_pose=0, reference_samples=0,
                 impairments=True, noise=True, seed=None):
        if isinstance(scene, (str, bytes)) or hasattr(scene, "__fspath__") or isinstance(scene, dict):
            scene = _scene.load_scene(scene)
        _check_radar(scene, sounding)
        self._scene = scene
        self._sounding = sounding
        self._K, self._M = sounding.num_tx, sounding.num_rx
        self._F = sounding.fft_len
        self._pre = self._F // 8
        if int(samples_per_pose) < 0 or int(reference_samples) < 0:
            raise ValueError("building_channel: samples_per_pose and reference_samples must be >= 0")
        self._samples_per_pose = int(samples_per_pose)
        self._reference_samples = int(reference_samples)
        self._fixed_pose = None if pose is None else self._check_pose(pose, "pose")
        self._message_pose = None
        gr.basic_block.__init__(self, name="building_channel", in_sig=[np.complex64] * self._K,
                                out_sig=[np.complex64] * self._M)
        self.set_tag_propagation_policy(gr.TPP_DONT)
        self.message_port_register_in(POSE_PORT)
        self.set_msg_handler(POSE_PORT, self._handle_pose)

        bins = np.arange(self._F)
        self._frequencies_hz = sounding.lo_frequency_hz + np.array([sounding.bin_frequency_hz(int(b)) for b in bins])
        imp = scene.impairments
        if impairments:
            self._alpha = _sim.chain_gains(imp["tx"], self._frequencies_hz)  # (K, F)
            self._beta = _sim.chain_gains(imp["rx"], self._frequencies_hz)  # (M, F)
            self._system = np.exp(-2j * np.pi * self._frequencies_hz * imp["system_delay_s"])
            self._dc = np.asarray(imp["dc_offset"], dtype=complex)
        else:
            self._alpha = np.ones((self._K, self._F), complex)
            self._beta = np.ones((self._M, self._F), complex)
            self._system = np.ones(self._F, complex)
            self._dc = np.zeros(self._M, complex)
        self._reference_amplitude = float(imp["rx_reference_amplitude"])
        self._noise = bool(noise)
        self._rng = np.random.default_rng(scene.seed if seed is None else seed)
        self._tail = np.zeros((self._K, self._F - 1), np.complex64)
        self._cache = {}
        self._current_key = None
        self._sent_time = False

    # ------------------------------------------------------------------------------------
    def _check_pose(self, pose, name):
        pose = np.asarray(pose, dtype=float)
        if pose.shape != (3,) or not np.all(np.isfinite(pose)):
            raise ValueError(f"building_channel: {name}: expected a finite [x, y, heading]")
        return pose

    def _handle_pose(self, msg):
        pose = pose_from_pmt(msg)
        if pose is None:
            self.logger.warn(f"ignoring a pose message without a finite [x, y, heading]: {pmt.write_string(msg)[:200]}")
            return
        self._message_pose = pose

    def scene(self):
        return self._scene

    def pose_at(self, output_sample):
        """The pose used for an output sample (message, fixed pose, or the trajectory)."""
        if self._message_pose is not None:
            return self._message_pose
        if self._fixed_pose is not None:
            return self._fixed_pose
        poses = self._scene.poses
        if self._samples_per_pose <= 0:
            return poses[0]
        index = max(0, output_sample - self._reference_samples) // self._samples_per_pose
        return poses[min(index, len(poses) - 1)]

    def _segment_end(self, output_sample):
        """The first output sample after output_sample whose channel may differ."""
        ends = []
        if output_sample < self._reference_samples:
            ends.append(self._reference_samples)
        elif self._samples_per_pose > 0 and self._message_pose is None and self._fixed_pose is None:
            rel = output_sample - self._reference_samples
            ends.append(self._reference_samples + (rel // self._samples_per_pose + 1) * self._samples_per_pose)
        return min(ends) if ends else None

    def frequency_response(self, pose, reference=False):
        """The channel applied at a pose, (K, M, F) over the FFT bins (FFT order)."""
        if reference:
            response = np.zeros((self._K, self._M, self._F), complex)
            response[0] = self._reference_amplitude * self._beta * self._system
            return response
        h = _sim.channel_matrix_at_pose(self._scene, pose, self._frequencies_hz)
        return h * self._alpha[:, None, :] * self._beta[None, :, :] * self._system

    def _filters(self, key, block):
        cached = self._cache.get((key, block))
        if cached is None:
            reference, pose = key[0], np.array(key[1:])
            response = self.frequency_response(pose, reference)
            impulse = np.fft.ifft(response, axis=-1)  # periodic, lags 0 ... F-1
            causal = np.roll(impulse, self._pre, axis=-1)  # lags -pre ... F-1-pre, delayed by pre
            cached = np.fft.fft(causal, n=block, axis=-1)
            if len(self._cache) > 16:
                self._cache.clear()
            noise_std = 0.0
            if self._noise:
                noise = self._scene.noise
                if "snr_db" in noise:
                    weights = _sim.scene_tx_weights(self._scene)
                    used = np.asarray(self._sounding.subcarrier_bins)
                    csi = np.einsum("k,kmn->mn", weights, response[:, :, used])
                    power = float(np.mean(np.abs(csi) ** 2)) / 10.0 ** (noise["snr_db"] / 10.0)
                else:
                    power = float(noise["power"])
                noise_std = math.sqrt(power * self._sounding.num_symbols / 2.0)
            cached = (cached, noise_std)
            self._cache[(key, block)] = cached
        return cached

    def forecast(self, noutput_items, ninputs):
        return [noutput_items] * ninputs

    def general_work(self, input_items, output_items):
        n_in = min(len(x) for x in input_items)
        n_out_room = len(output_items[0])
        read = self.nitems_read(0)
        written = self.nitems_written(0)
        lag = read - written  # grows to pre at the start, then stays
        count = min(n_in, n_out_room + self._pre - lag, _CHUNK)
        if count <= 0:
            return 0
        first_output = read - self._pre  # output index of the first new input's result
        key_sample = max(first_output, 0)
        end = self._segment_end(key_sample)
        if end is not None:
            count = min(count, max(1, end + self._pre - read))
        reference = key_sample < self._reference_samples
        pose = self.pose_at(key_sample)
        key = (reference,) + tuple(float(v) for v in pose)
        block = 1 << int(math.ceil(math.log2(count + self._F - 1)))
        spectra, noise_std = self._filters(key, block)

        x = np.concatenate((self._tail, np.stack([np.asarray(v[:count]) for v in input_items])), axis=1)
        xf = np.fft.fft(x, n=block, axis=1)
        y = np.fft.ifft(np.einsum("kb,kmb->mb", xf, spectra), axis=1)[:, self._F - 1:self._F - 1 + count]
        self._tail = x[:, -(self._F - 1):].astype(np.complex64)
        y += self._dc[:, None]
        if noise_std > 0:
            y += noise_std * (self._rng.standard_normal(y.shape) + 1j * self._rng.standard_normal(y.shape))
        drop = max(0, min(count, -first_output))  # results for output indices < 0
        produced = count - drop
        for m in range(self._M):
            output_items[m][:produced] = y[m, drop:]

        if produced:
            out_first = written
            if key != self._current_key:
                if self._current_key is None and self._reference_samples == 0:
                    self._tag_all(out_first, KEY_FRAME_TYPE, pmt.intern("survey"))
                if self._current_key is None:
                    self._tag_all(out_first, KEY_RX_FREQ, pmt.from_double(float(self._sounding.lo_frequency_hz)))
                if reference:
                    self._tag_all(out_first, KEY_FRAME_TYPE, pmt.intern("rx_reference"))
                else:
                    if self._current_key is not None and self._current_key[0]:
                        self._tag_all(out_first, KEY_FRAME_TYPE, pmt.intern("survey"))
                    self._tag_all(out_first, KEY_POSE, pmt.init_f64vector(3, [float(v) for v in pose]))
                self._current_key = key
        if not self._sent_time:
            for tag in self.get_tags_in_window(0, 0, count, KEY_TX_TIME):
                self._tag_all(tag.offset, KEY_RX_TIME, tag.value)
                self._sent_time = True
                break
        self.consume_each(count)
        return produced

    def _tag_all(self, offset, key, value):
        for m in range(self._M):
            self.add_item_tag(m, offset, key, value)
