/* -*- c++ -*- */
/*
 * SPDX-License-Identifier: GPL-3.0-or-later
 */
#ifndef INCLUDED_THRUMAPPER_CHANNEL_CALIBRATOR_H
#define INCLUDED_THRUMAPPER_CHANNEL_CALIBRATOR_H

#include <gnuradio/block.h>
#include <gnuradio/thrumapper/api.h>
#include <gnuradio/thrumapper/channel_calibration.h>
#include <gnuradio/thrumapper/ofdm_sounding.h>
#include <cstdint>
#include <string>

namespace gr {
namespace thrumapper {

/*!
 * \brief Multichannel RX calibration (paper §3.3): DC offset removal, amplitude
 * equalisation, phase and delay alignment, on M sample streams.
 * \ingroup thrumapper
 *
 * M streams in, M streams out, sample for sample (tags pass through). The coefficients are
 * estimated (channel_calibration) from the next calibration_len input samples at start
 * (calibrate_at_start), after a retune (an rx_freq tag on input 0 with a new value) and
 * after a message on the "calibrate" port; meanwhile the samples must hold the reference
 * (source "reference": a signal split equally into every chain) or the sounder's direct
 * path (source "direct_path"). New coefficients are applied, under a lock, from the next
 * frame boundary (frame_offset + i·frame_len) on; they go out as a dict on the
 * "coefficients" port ({"dc": c64vector, "gain_db", "phase_rad", "delay_s": f64vector,
 * "reference_channel": long, "source": symbol, "center_frequency_hz": double,
 * "sample_offset": uint64 where they apply, "calibration_index": uint64}) and are written
 * to coefficients_path (JSON, calibration_coefficients) when it is set. When that file
 * exists at start, it is loaded and applied from sample 0.
 */
class THRUMAPPER_API channel_calibrator : virtual public gr::block
{
public:
    typedef std::shared_ptr<channel_calibrator> sptr;

    /*!
     * \param sounding the waveform (M, FFT size, sample rate, frame length).
     * \param source "reference" or "direct_path".
     * \param calibration_len samples per estimate (>= fft_len); 0: 8 frames.
     * \param reference_channel the channel the others are aligned to; -1: their mean.
     * \param calibrate_at_start estimate from the first calibration_len samples.
     * \param coefficients_path JSON file to load at start (if it exists) and save to; "" none.
     * \param frame_offset stream sample of a frame start (where updates may apply).
     */
    static sptr make(ofdm_sounding::sptr sounding,
                     const std::string& source = "reference",
                     int calibration_len = 0,
                     int reference_channel = 0,
                     bool calibrate_at_start = true,
                     const std::string& coefficients_path = "",
                     int64_t frame_offset = 0);

    //! Estimate again from the next calibration_len samples (as the "calibrate" message).
    virtual void calibrate() = 0;
    //! Apply these coefficients from the next frame boundary.
    virtual void set_coefficients(const calibration_coefficients& c) = 0;
    //! The coefficients in use now.
    virtual calibration_coefficients coefficients() const = 0;
    virtual void save_coefficients(const std::string& path) const = 0;
    //! Load from a JSON file and apply from the next frame boundary.
    virtual void load_coefficients(const std::string& path) = 0;
    //! Estimates made since start.
    virtual uint64_t num_calibrations() const = 0;
    //! Estimates that failed (no signal, NaN/Inf): logged, counted, coefficients kept.
    virtual uint64_t num_failed_calibrations() const = 0;
    //! True while samples for an estimate are being collected or the result waits to apply.
    virtual bool calibration_pending() const = 0;
    virtual int calibration_len() const = 0;
};

} // namespace thrumapper
} // namespace gr

#endif
