/* -*- c++ -*- */
/*
 * SPDX-License-Identifier: GPL-3.0-or-later
 */
#ifndef INCLUDED_THRUMAPPER_OFDM_SOUNDING_H
#define INCLUDED_THRUMAPPER_OFDM_SOUNDING_H

#include <gnuradio/fft/fft.h>
#include <gnuradio/gr_complex.h>
#include <gnuradio/thrumapper/api.h>
#include <gnuradio/thrumapper/radar_description.h>
#include <memory>
#include <string>
#include <vector>

namespace gr {
namespace thrumapper {

//! How the TX elements share a sounding frame.
enum class sounding_mode {
    //! every element sends the same symbol times its weight w_k (eq. 1)
    weighted = 0,
    //! calibration: one training slot per element, the others silent
    sequential = 1,
    //! calibration: element k alone on the used subcarriers n with n mod K = k
    interleaved = 2,
};

/*!
 * \brief The OFDM sounding waveform: frame layout, preamble, pilots (docs/radio-chain.md).
 * \ingroup thrumapper
 *
 * A frame (all lengths in samples at sample_rate_hz):
 *
 *     | preamble (preamble_len) | slot 0 | ... | slot S-1 | gap (gap_len, zeros) |
 *     slot = | cyclic prefix (cp_len) | guard period (fft_len) |
 *            | num_symbols estimation periods (fft_len each) | cyclic postfix (cp_len) |
 *
 * The preamble is a constant-envelope chirp (a Zadoff-Chu sequence in time) for frame timing.
 * A slot is the pilot symbol repeated periodically, so every symbol's cyclic prefix is the
 * end of the symbol before it. The guard period lets every echo and every filter transient
 * of the burst's start settle (the band-limited response of a fractional delay has long
 * tails), so that the estimation windows see a periodic signal and their least-squares
 * estimate equals the channel on the subcarriers exactly. The pilots are a Zadoff-Chu sequence on the used
 * subcarriers (|X_n| = 1, constant envelope in time when the used bins are every bin or
 * every other bin). Subcarrier n, at fc + Δf_n (the radar description's offsets), is FFT bin
 * k_n = (Δf_n - tuning_offset_hz) / (sample_rate_hz / fft_len), which must be a whole number
 * and not 0: no subcarrier sits on the radios' DC. With the default 120 MS/s and fft_len 256,
 * the 128 subcarriers of a 120 MHz radar are the odd bins ±1 ... ±127.
 *
 * Every element's frame has zero mean (its preamble carries the small constant that makes it
 * so), so the mean over whole frames of a received channel is its DC offset alone.
 * S = 1, except in sequential mode, where S = K (slot k: element k alone). Sample-level
 * normalisation: the FFT is unitary, so a channel of gain 1 gives an estimate of 1.
 * Immutable: share one between the sounder, the estimator and the calibrator.
 */
class THRUMAPPER_API ofdm_sounding
{
public:
    typedef std::shared_ptr<ofdm_sounding> sptr;

    /*!
     * \param radar the radar (subcarrier offsets, carrier, K, M, default weights).
     * \param sample_rate_hz sample rate of every TX and RX channel.
     * \param fft_len FFT size; sample_rate_hz / fft_len must divide the subcarrier offsets.
     * \param cp_len cyclic prefix (and postfix) of every slot, > the longest echo.
     * \param num_symbols estimation periods per slot (the estimator averages them).
     * \param preamble_len preamble length (>= 16).
     * \param gap_len silence after the last slot.
     * \param mode weighted, sequential or interleaved.
     * \param tuning_offset_hz the radios tune to carrier + tuning_offset_hz.
     */
    static sptr make(radar_description::sptr radar,
                     double sample_rate_hz = 120e6,
                     int fft_len = 256,
                     int cp_len = 64,
                     int num_symbols = 4,
                     int preamble_len = 128,
                     int gap_len = 64,
                     sounding_mode mode = sounding_mode::weighted,
                     double tuning_offset_hz = 0.0);

    ofdm_sounding(radar_description::sptr radar,
                  double sample_rate_hz,
                  int fft_len,
                  int cp_len,
                  int num_symbols,
                  int preamble_len,
                  int gap_len,
                  sounding_mode mode,
                  double tuning_offset_hz);

    radar_description::sptr radar() const { return d_radar; }
    double sample_rate_hz() const { return d_sample_rate_hz; }
    //! Spacing of the FFT bins, sample_rate_hz / fft_len.
    double bin_spacing_hz() const { return d_sample_rate_hz / d_fft_len; }
    double tuning_offset_hz() const { return d_tuning_offset_hz; }
    //! The frequency the radios tune to: carrier + tuning offset.
    double lo_frequency_hz() const { return d_radar->carrier_hz() + d_tuning_offset_hz; }
    int fft_len() const { return d_fft_len; }
    int cp_len() const { return d_cp_len; }
    int num_symbols() const { return d_num_symbols; }
    int preamble_len() const { return d_preamble_len; }
    int gap_len() const { return d_gap_len; }
    sounding_mode mode() const { return d_mode; }
    int num_tx() const { return d_radar->num_tx(); }
    int num_rx() const { return d_radar->num_rx(); }
    int num_subcarriers() const { return d_radar->num_subcarriers(); }
    //! Training slots per frame: K in sequential mode, else 1.
    int num_slots() const { return d_mode == sounding_mode::sequential ? num_tx() : 1; }
    //! CSI items per frame (one per slot).
    int items_per_frame() const { return num_slots(); }
    int slot_len() const { return 2 * d_cp_len + (d_num_symbols + 1) * d_fft_len; }
    //! Preamble and slots: the part of the frame that is not silence.
    int burst_len() const { return d_preamble_len + num_slots() * slot_len(); }
    int frame_len() const { return burst_len() + d_gap_len; }
    double frame_duration_s() const { return frame_len() / d_sample_rate_hz; }
    //! First sample of slot s (its cyclic prefix), from the frame start.
    int slot_start(int slot) const { return d_preamble_len + slot * slot_len(); }
    //! First sample of estimation window j of slot s, from the frame start.
    int window_start(int slot, int symbol) const
    {
        return slot_start(slot) + d_cp_len + (symbol + 1) * d_fft_len;
    }
    //! FFT bin (0 ... fft_len-1) of every used subcarrier.
    const std::vector<int>& subcarrier_bins() const { return d_bins; }
    //! Signed FFT bin of every used subcarrier (-fft_len/2 ... fft_len/2).
    const std::vector<int>& subcarrier_signed_bins() const { return d_signed_bins; }
    //! Baseband frequency of FFT bin index (0 ... fft_len-1), Hz from the LO.
    double bin_frequency_hz(int bin) const;
    //! The pilots X_n, one per used subcarrier, |X_n| = 1.
    const std::vector<gr_complex>& pilots() const { return d_pilots; }
    //! The preamble, preamble_len samples (before the TX weight).
    const std::vector<gr_complex>& preamble() const { return d_preamble; }
    //! The TX element sounding subcarrier n: n mod K in interleaved mode, else -1 (all).
    int tx_element_of_subcarrier(int n) const;

    /*!
     * \brief One frame of TX element `element`, frame_len samples, into out.
     * In weighted mode the whole burst is multiplied by weights[element] (empty: the radar's
     * weights); the calibration modes ignore the weights (every element at weight 1).
     */
    void frame_samples(int element,
                       const std::vector<gr_complex>& weights,
                       gr_complex* out) const;
    //! The unweighted frame of one element (frame_samples with weight 1).
    const std::vector<gr_complex>& unweighted_frame(int element) const
    {
        return d_frames.at(element);
    }
    std::string to_string() const;

private:
    radar_description::sptr d_radar;
    double d_sample_rate_hz;
    int d_fft_len, d_cp_len, d_num_symbols, d_preamble_len, d_gap_len;
    sounding_mode d_mode;
    double d_tuning_offset_hz;
    std::vector<int> d_bins, d_signed_bins;
    std::vector<gr_complex> d_pilots, d_preamble;
    std::vector<std::vector<gr_complex>> d_frames; // K unweighted frames
};

/*!
 * \brief Frame timing and least-squares channel estimation for one ofdm_sounding.
 * \ingroup thrumapper
 *
 * Owns FFT plans and buffers: one per thread. Every call takes M channel pointers that
 * point at the search origin, search_window samples before the frame's nominal start, with
 * span() samples readable behind each.
 */
class THRUMAPPER_API ofdm_demodulator
{
public:
    struct detection {
        bool found;
        int offset;    //!< samples from the nominal frame start to the preamble's peak
        double metric; //!< normalised correlation at the peak, 0 ... 1
    };

    /*!
     * \param sounding the waveform.
     * \param search_window the preamble is searched within ± this many samples.
     * \param timing_backoff windows start this many samples before the detected timing.
     * \param detection_threshold minimum normalised preamble correlation (0 ... 1).
     */
    ofdm_demodulator(ofdm_sounding::sptr sounding,
                     int search_window,
                     int timing_backoff,
                     double detection_threshold);
    ~ofdm_demodulator();
    ofdm_demodulator(const ofdm_demodulator&) = delete;
    ofdm_demodulator& operator=(const ofdm_demodulator&) = delete;

    //! Samples needed per channel from the search origin: burst_len + 2·search_window.
    int span() const;
    int search_window() const { return d_search_window; }
    int timing_backoff() const { return d_backoff; }
    double detection_threshold() const { return d_threshold; }
    const ofdm_sounding::sptr& sounding() const { return d_sounding; }

    //! Finds the preamble jointly over the channels (the channels share one clock).
    detection detect(const gr_complex* const* channels, int num_channels);
    /*!
     * \brief Least-squares CSI of every slot: items_per_frame × M × N into csi
     * (item-major, then element-major: csi[(s·M + m)·N + n]).
     * \param offset the detected timing (detection::offset).
     * \param fractional_offset_samples where the nominal frame start really lies, in samples
     *        after the integer start the pointers assume (from time tags, |.| < 1); the CSI
     *        is referred to the nominal start.
     */
    void estimate(const gr_complex* const* channels,
                  int num_channels,
                  int offset,
                  double fractional_offset_samples,
                  gr_complex* csi);

private:
    ofdm_sounding::sptr d_sounding;
    int d_search_window, d_backoff;
    double d_threshold;
    int d_corr_len;
    std::unique_ptr<gr::fft::fft_complex_fwd> d_fft, d_corr_fwd;
    std::unique_ptr<gr::fft::fft_complex_rev> d_corr_rev;
    std::vector<gr_complex> d_preamble_spectrum; // conj(FFT(preamble)) at d_corr_len
    std::vector<float> d_metric_num, d_metric_den;
    std::vector<double> d_energy_prefix;
    std::vector<gr_complex> d_acc;
    std::vector<gr_complex> d_phasors; // e^{-j2πi/F}, i = 0 ... F-1
    double d_preamble_energy;
};

} // namespace thrumapper
} // namespace gr

#endif
