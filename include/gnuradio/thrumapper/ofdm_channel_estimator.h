/* -*- c++ -*- */
/*
 * SPDX-License-Identifier: GPL-3.0-or-later
 */
#ifndef INCLUDED_THRUMAPPER_OFDM_CHANNEL_ESTIMATOR_H
#define INCLUDED_THRUMAPPER_OFDM_CHANNEL_ESTIMATOR_H

#include <gnuradio/block.h>
#include <gnuradio/thrumapper/api.h>
#include <gnuradio/thrumapper/ofdm_sounding.h>
#include <cstdint>

namespace gr {
namespace thrumapper {

/*!
 * \brief Frame timing, CP removal, FFT and least-squares CSI for the M RX streams.
 * \ingroup thrumapper
 *
 * Inputs: M complex streams sharing one clock. Frames are expected on the grid
 * frame_offset + i·frame_len (stream samples); the preamble is searched jointly over the
 * channels within ± search_window of each grid position, and the estimation windows follow
 * the detected timing (less timing_backoff). The CSI is referred to the grid position, so
 * it keeps the absolute delay (τ_sys included), as a CSI survey does. With frame_offset -1
 * (radios not started at a known time) the grid is acquired from the first preamble found
 * in a search over whole frame periods: the CSI's delays are then relative to that
 * preamble's strongest arrival, not to the transmit time.
 *
 * Output: items_per_frame vector items per frame of M·N gr_complex, element-major (entry
 * m·N + n), the layout jade_estimator and survey_sink take. Tags on each item:
 * "frame_index" (uint64: i), "rx_time" (tuple uint64 s, double frac: the time of the frame's
 * grid position, from the latest rx_time tag, or from sample 0 at time 0),
 * "timing_offset" (long, samples: the detected offset from the grid), "preamble_metric"
 * (double), and, as last seen on input 0, "pose", "rx_freq" and "frame_type". Sequential
 * sounding: one item per TX element with "tx_element" (long) and "tx_weights" (c64vector,
 * the unit vector of that element). Interleaved: "sounding_mode" = interleaved; subcarrier n
 * is the channel of TX element n mod K.
 *
 * Skipped and counted, never output: frames whose preamble is missing or damaged (normalised
 * correlation below detection_threshold, or NaN/Inf samples), and frames cut by a stream
 * discontinuity. A USRP overflow shows as an rx_time tag whose time disagrees with the
 * sample count: the grid is moved by the lost samples, so the frames after it keep their
 * timing and indices.
 */
class THRUMAPPER_API ofdm_channel_estimator : virtual public gr::block
{
public:
    typedef std::shared_ptr<ofdm_channel_estimator> sptr;

    /*!
     * \param sounding the waveform.
     * \param frame_offset stream sample of frame 0's start (the sounder's first sample);
     *        -1: acquire it from the first preamble.
     * \param search_window preamble search range, ± samples; -1: cp_len.
     * \param timing_backoff windows start this much before the detected timing; -1: cp_len/4.
     * \param detection_threshold minimum normalised preamble correlation, 0 ... 1.
     */
    static sptr make(ofdm_sounding::sptr sounding,
                     int64_t frame_offset = 0,
                     int search_window = -1,
                     int timing_backoff = -1,
                     double detection_threshold = 0.3);

    virtual void set_detection_threshold(double threshold) = 0;
    virtual double detection_threshold() const = 0;
    virtual int search_window() const = 0;
    virtual int timing_backoff() const = 0;
    //! Frames estimated and output.
    virtual uint64_t num_frames() const = 0;
    //! Frames skipped: no preamble found (missing, damaged, NaN/Inf).
    virtual uint64_t num_missing_preamble() const = 0;
    //! Frames skipped because a stream discontinuity (overflow) cut them or they were lost.
    virtual uint64_t num_discontinuity_skips() const = 0;
    //! Discontinuities seen (rx_time tags that disagree with the sample count).
    virtual uint64_t num_discontinuities() const = 0;
};

} // namespace thrumapper
} // namespace gr

#endif
