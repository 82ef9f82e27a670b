/* -*- c++ -*- */
/*
 * SPDX-License-Identifier: GPL-3.0-or-later
 */
#ifndef INCLUDED_THRUMAPPER_CHANNEL_CALIBRATION_H
#define INCLUDED_THRUMAPPER_CHANNEL_CALIBRATION_H

#include <gnuradio/fft/fft.h>
#include <gnuradio/gr_complex.h>
#include <gnuradio/thrumapper/api.h>
#include <gnuradio/thrumapper/ofdm_sounding.h>
#include <memory>
#include <string>
#include <vector>

namespace gr {
namespace thrumapper {

/*!
 * \brief Per-channel RX chain corrections (paper §3.3): DC offset, gain, phase, delay.
 * \ingroup thrumapper
 *
 * Chain m is modelled as y_m = β_m ∗ x + dc_m with β_m(f) = 10^{gain_db/20} ·
 * e^{j·phase_rad} · e^{-j2π·f·delay_s}, f the baseband frequency from the LO, relative to
 * the reference channel (whose values are 0). The correction subtracts dc_m and divides by
 * β_m. JSON form (save/load): {"thrumapper:calibration": 1, "num_channels": M,
 * "reference_channel", "source", "center_frequency_hz", "sample_rate_hz", "channels":
 * [{"dc": [re, im], "gain_db", "phase_rad", "delay_s"}, ...]}.
 */
struct THRUMAPPER_API calibration_coefficients {
    std::vector<gr_complex> dc;
    std::vector<double> gain_db;
    std::vector<double> phase_rad;
    std::vector<double> delay_s;
    //! The channel the others are aligned to; -1: aligned to the mean of all channels.
    int reference_channel = 0;
    //! "reference" (split reference signal), "direct_path", "identity" or "file".
    std::string source = "identity";
    double center_frequency_hz = 0.0;
    double sample_rate_hz = 0.0;

    //! No correction for num_channels channels.
    static calibration_coefficients identity(int num_channels);
    int num_channels() const { return static_cast<int>(gain_db.size()); }
    //! Checks sizes and finiteness; throws std::invalid_argument naming the field.
    void validate() const;
    //! The chain response β_m at baseband frequency f (Hz from the LO).
    gr_complex chain_response(int channel, double baseband_hz) const;
    std::string to_json() const;
    static calibration_coefficients from_json(const std::string& text);
    //! Writes to_json() to path (through a temporary file and a rename).
    void save(const std::string& path) const;
    static calibration_coefficients load(const std::string& path);
};

/*!
 * \brief Estimates the RX chains' relative DC offset, gain, phase and delay.
 * \ingroup thrumapper
 *
 * From a segment of samples of all M channels recorded while they received one common
 * signal: either a reference split equally into every chain (source "reference": FORMATS.md's
 * rx_reference), or the sounder's direct TX→RX path, whose per-element coupling is known
 * from the geometry (source "direct_path": spherical wavefronts, the radar's TX weights,
 * free space around the radar). In the paper's order: (i) DC offset: each channel's mean
 * over the segment's whole frames (a sounding frame has no DC);
 * (ii) amplitude: the mean magnitude of the cross-spectrum ratio to the reference channel;
 * (iii) phase and delay: the ratio's phase at the LO and its slope over frequency (weighted
 * least squares over the bins that carry signal, after a coarse delay from the mean phase
 * step between neighbouring bins).
 */
class THRUMAPPER_API channel_calibration
{
public:
    channel_calibration(ofdm_sounding::sptr sounding,
                        const std::string& source = "reference",
                        int reference_channel = 0,
                        const std::vector<gr_complex>& tx_weights = {});
    ~channel_calibration();
    channel_calibration(const channel_calibration&) = delete;
    channel_calibration& operator=(const channel_calibration&) = delete;

    /*!
     * \param channels M pointers with length samples each (length >= fft_len).
     * \param center_frequency_hz the radios' carrier (for the direct-path model); 0 means
     *        the radar's carrier.
     */
    calibration_coefficients estimate(const gr_complex* const* channels,
                                      int num_channels,
                                      int length,
                                      double center_frequency_hz = 0.0);
    const std::string& source() const { return d_source; }
    int reference_channel() const { return d_reference; }

private:
    ofdm_sounding::sptr d_sounding;
    std::string d_source;
    int d_reference;
    std::vector<gr_complex> d_weights;
    std::unique_ptr<gr::fft::fft_complex_fwd> d_fft;
};

/*!
 * \brief Applies calibration_coefficients to M sample streams.
 * \ingroup thrumapper
 *
 * Per channel: out = FIR_m(x) - dc_m·C_m(0), where FIR_m is the frequency-sampling design
 * (fft_len taps, lags -fft_len/2 ... fft_len/2-1) of C_m(f) = 1/β_m(f) at the FFT bins:
 * exact on every bin, so on the sounding's periodic slots. Overlap-save with gr::fft.
 * process() takes taps()-1 samples of history before the first output's window and needs
 * lookahead() samples after it.
 */
class THRUMAPPER_API channel_corrector
{
public:
    channel_corrector(int num_channels, int fft_len, double sample_rate_hz);
    ~channel_corrector();
    channel_corrector(const channel_corrector&) = delete;
    channel_corrector& operator=(const channel_corrector&) = delete;

    void set_coefficients(const calibration_coefficients& c);
    const calibration_coefficients& coefficients() const { return d_coefficients; }
    int taps() const { return d_taps; }
    int lookahead() const { return d_taps / 2; }
    /*!
     * \brief n corrected samples of one channel. in points at the first of
     * n + taps() - 1 input samples; out[i] is the corrected input sample
     * in[i + taps() - 1 - lookahead()].
     */
    void process(int channel, const gr_complex* in, gr_complex* out, int n);

private:
    int d_channels, d_taps, d_block;
    double d_sample_rate_hz;
    calibration_coefficients d_coefficients;
    std::vector<std::vector<gr_complex>> d_spectra; // per channel, d_block bins (scaled)
    std::vector<bool> d_identity;
    std::vector<gr_complex> d_dc_term;
    std::unique_ptr<gr::fft::fft_complex_fwd> d_fwd;
    std::unique_ptr<gr::fft::fft_complex_rev> d_rev;
};

} // namespace thrumapper
} // namespace gr

#endif
