/* -*- c++ -*- */
/*
 * SPDX-License-Identifier: GPL-3.0-or-later
 */
#ifndef INCLUDED_THRUMAPPER_OFDM_SOUNDER_H
#define INCLUDED_THRUMAPPER_OFDM_SOUNDER_H

#include <gnuradio/sync_block.h>
#include <gnuradio/thrumapper/api.h>
#include <gnuradio/thrumapper/ofdm_sounding.h>
#include <cstdint>
#include <vector>

namespace gr {
namespace thrumapper {

/*!
 * \brief OFDM sounding bursts for the K TX elements, one output stream per element.
 * \ingroup thrumapper
 *
 * Frame after frame of the ofdm_sounding waveform, back to back. In weighted mode element
 * k sends the frame times w_k (eq. 1); the calibration modes ignore the weights.
 *
 * Tags, on every output, for timed USRP transmission: "tx_sob" (true) on each frame's
 * first sample, "tx_eob" (true) on its last, "tx_time" (tuple of uint64 whole seconds and
 * double fraction: start_time_s + i·frame_duration) on the first sample when start_time_s
 * >= 0, "frame_index" (uint64) on the first sample, and "tx_weights" (c64vector of K) on
 * the first frame and whenever the weights change.
 *
 * Message port "weights": a dict with key "weights" holding a c32vector or c64vector of K
 * values (what null_steering_weights sends), or a bare c32vector/c64vector. New weights
 * take effect at the next frame; a malformed message is logged, counted
 * (num_rejected_weights()) and ignored.
 */
class THRUMAPPER_API ofdm_sounder : virtual public gr::sync_block
{
public:
    typedef std::shared_ptr<ofdm_sounder> sptr;

    /*!
     * \param sounding the waveform.
     * \param weights K TX weights; empty: the radar description's.
     * \param start_time_s tx_time of frame 0 (USRP time, s); negative: no tx_time tags.
     */
    static sptr make(ofdm_sounding::sptr sounding,
                     const std::vector<gr_complex>& weights = {},
                     double start_time_s = -1.0);

    //! Thread safe; takes effect at the next frame boundary.
    virtual void set_weights(const std::vector<gr_complex>& weights) = 0;
    //! The weights of the frames now being sent (or about to be, if just set).
    virtual std::vector<gr_complex> weights() const = 0;
    //! Frames started so far.
    virtual uint64_t num_frames() const = 0;
    virtual uint64_t num_rejected_weights() const = 0;
};

} // namespace thrumapper
} // namespace gr

#endif
