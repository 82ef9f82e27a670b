/* -*- c++ -*- */
/*
 * SPDX-License-Identifier: GPL-3.0-or-later
 */
#ifndef INCLUDED_THRUMAPPER_NULL_STEERING_WEIGHTS_H
#define INCLUDED_THRUMAPPER_NULL_STEERING_WEIGHTS_H

#include <gnuradio/sync_block.h>
#include <gnuradio/thrumapper/api.h>
#include <gnuradio/thrumapper/radar_description.h>
#include <vector>

namespace gr {
namespace thrumapper {

/*!
 * \brief TX weights with a main lobe toward the walls and nulls toward the receiver and
 * corners, for the OFDM sounder; and the beam pattern they make.
 * \ingroup thrumapper
 *
 * Message port "weights": published at start and after every change, a dict with lowercase
 * keys {"weights": c32vector of K, "main_lobe_deg", "null_angles_deg": f64vector,
 * "null_receiver": bool, "coupling_db": the direct coupling relative to a beam aimed at the
 * receiver}.
 *
 * Output: the far-field gain (dB over an isotropic element, averaged over the band) at
 * num_angles bearings over [0, 360), for qtgui.vector_sink_f; one vector when the weights
 * change and then every update_period_s.
 *
 * Bearings are seen from the TX array centre, CCW from robot +x. See null_steering for the
 * design (LCMV: unit gain toward the main lobe, zeros toward the far-field nulls, the
 * least-squares null of the exact near-field coupling to the receiving array).
 */
class THRUMAPPER_API null_steering_weights : virtual public gr::sync_block
{
public:
    typedef std::shared_ptr<null_steering_weights> sptr;

    static sptr make(radar_description::sptr radar,
                     double main_lobe_deg = 300.0,
                     bool null_receiver = true,
                     const std::vector<double>& null_angles_deg = {},
                     int num_angles = 360,
                     double update_period_s = 0.5);

    virtual void set_main_lobe(double main_lobe_deg) = 0;
    virtual void set_null_angles(const std::vector<double>& null_angles_deg) = 0;
    virtual void set_null_receiver(bool null_receiver) = 0;

    virtual std::vector<gr_complex> weights() const = 0;
    //! Direct coupling of the current weights, dB relative to a beam aimed at the receiver.
    virtual double coupling_db() const = 0;
    //! The coupling to expect with this rms phase error on every TX chain, dB.
    virtual double expected_coupling_db(double phase_error_deg) const = 0;
};

} // namespace thrumapper
} // namespace gr

#endif
