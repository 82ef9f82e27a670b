/* -*- c++ -*- */
/*
 * SPDX-License-Identifier: GPL-3.0-or-later
 */
#ifndef INCLUDED_THRUMAPPER_PROJECTION_CANCELLER_H
#define INCLUDED_THRUMAPPER_PROJECTION_CANCELLER_H

#include <gnuradio/block.h>
#include <gnuradio/thrumapper/api.h>
#include <gnuradio/thrumapper/radar_description.h>
#include <cstdint>
#include <vector>

namespace gr {
namespace thrumapper {

/*!
 * \brief Removes known paths from CSI frames by projection (paper eq. 10).
 * \ingroup thrumapper
 *
 * In and out: one M·N gr_complex vector item per frame, element-major (entry m·N + n). Each
 * frame is projected onto the orthogonal complement of the given far-field paths' space-time
 * manifold vectors and, when cancel_direct, of the direct TX→RX path's exact near-field
 * response for the current TX weights (see path_projector).
 *
 * Message port "paths" (in): a dict with "paths", a vector or list of dicts {"angle_deg",
 * "delay_s"} — jade_estimator's "paths" message works as it is — replaces the paths to
 * cancel; {"clear": #t} clears them. Message port "weights" (in): null_steering_weights'
 * message (a dict with "weights"), or a bare c32vector, sets the TX weights of the direct path;
 * a "tx_weights" tag (c32/c64vector) on a frame sets them for that frame only. While the
 * direct path is cancelled, every frame out carries a "direct_path_weights" tag (c32vector):
 * the TX weights of the direct path cancelled from it (jade_estimator passes it on to
 * wall_fusion, whose CSI fits need the frames' TX weights).
 * A malformed message is logged and counted (num_bad_messages()); changes take effect at the
 * next frame. Frames with NaN/Inf are logged, counted (num_skipped()) and dropped.
 */
class THRUMAPPER_API projection_canceller : virtual public gr::block
{
public:
    typedef std::shared_ptr<projection_canceller> sptr;

    static sptr make(radar_description::sptr radar,
                     const std::vector<double>& aoa_deg = {},
                     const std::vector<double>& delay_s = {},
                     bool cancel_direct = false,
                     double system_delay_s = 0.0);

    virtual void set_paths(const std::vector<double>& aoa_deg, const std::vector<double>& delay_s) = 0;
    virtual void set_cancel_direct(bool cancel_direct) = 0;
    virtual void set_system_delay(double system_delay_s) = 0;
    virtual void set_tx_weights(const std::vector<gr_complex>& weights) = 0;
    //! The number of independent directions cancelled now.
    virtual int rank() const = 0;
    virtual uint64_t num_skipped() const = 0;
    virtual uint64_t num_bad_messages() const = 0;
};

} // namespace thrumapper
} // namespace gr

#endif
