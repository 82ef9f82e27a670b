/* -*- c++ -*- */
/*
 * SPDX-License-Identifier: GPL-3.0-or-later
 */
#ifndef INCLUDED_THRUMAPPER_JADE_ESTIMATOR_H
#define INCLUDED_THRUMAPPER_JADE_ESTIMATOR_H

#include <gnuradio/block.h>
#include <gnuradio/thrumapper/api.h>
#include <gnuradio/thrumapper/radar_description.h>
#include <cstdint>

namespace gr {
namespace thrumapper {

/*!
 * \brief Joint angle-delay estimation (JADE) on every CSI frame.
 * \ingroup thrumapper
 *
 * Input: one vector item per frame, M·N gr_complex, element-major (entry m·N + n: RX element
 * m, subcarrier n), as survey_source and ofdm_channel_estimator produce it.
 *
 * Output 0: the MUSIC pseudo-spectrum in dB, one float vector of num_angles·num_delays per
 * frame, angle-major (entry a·num_delays + d), ready for qtgui.time_raster_sink (after a
 * vector_to_stream, num_delays columns, num_angles rows per frame).
 *
 * Message port "paths": one PMT dict per frame with lowercase keys: "frame_index" (uint64),
 * "rx_time" (as tagged, when the frame carries an rx_time tag), "pose" (f64vector, when
 * tagged), "model_order" (long) and "paths": a PMT vector of dicts {"angle_deg", "delay_s",
 * "power", "spectrum_db", "stage"}, strongest first. Angle: degrees in [0, 360) CCW from robot
 * +x at the RX centre; delay: TX centre to RX centre, system delay removed (FORMATS.md).
 * With attach_csi the dict also carries the frame as JADE saw it, for wall_fusion's CSI fits:
 * "csi" (c32vector, M·N, element-major), "system_delay_s" (double), "tx_weights" (the frame's
 * "tx_weights" tag, else its "direct_path_weights" tag, when tagged) and
 * "direct_path_cancelled" (bool: a projection_canceller upstream tagged the frame with the
 * "direct_path_weights" it cancelled).
 *
 * A frame with NaN/Inf values, the wrong size or no signal is skipped: logged, counted
 * (num_skipped()), and gives no output item. All setters are thread safe and take effect at
 * the next frame; the grid sizes are fixed by the output vector length.
 */
class THRUMAPPER_API jade_estimator : virtual public gr::block
{
public:
    typedef std::shared_ptr<jade_estimator> sptr;

    /*!
     * \param radar the radar description (RX geometry, carrier, subcarriers).
     * \param num_angles angle grid size; the grid spans [angle_min_deg, angle_max_deg),
     *        the full circle by default.
     * \param angle_min_deg, angle_max_deg angle grid span, degrees.
     * \param num_delays delay grid size over [delay_min_s, delay_max_s].
     * \param delay_min_s, delay_max_s delay grid span, seconds, system delay removed.
     * \param max_paths most paths reported per frame.
     * \param smoothing_window subcarriers per smoothing window L; 0 means N/3.
     * \param system_delay_s τ_sys, removed from every delay.
     * \param stages successive-cancellation stages (1: estimate once); each path's "stage"
     *        says which stage found it.
     * \param attach_csi attach each frame's CSI to its "paths" message (above).
     */
    static sptr make(radar_description::sptr radar,
                     int num_angles = 360,
                     double angle_min_deg = 0.0,
                     double angle_max_deg = 360.0,
                     int num_delays = 200,
                     double delay_min_s = 0.0,
                     double delay_max_s = 40e-9,
                     int max_paths = 4,
                     int smoothing_window = 0,
                     double system_delay_s = 0.0,
                     int stages = 1,
                     bool attach_csi = false);

    virtual void set_angle_span(double angle_min_deg, double angle_max_deg) = 0;
    virtual void set_delay_span(double delay_min_s, double delay_max_s) = 0;
    virtual void set_max_paths(int max_paths) = 0;
    virtual void set_smoothing_window(int subcarriers) = 0;
    virtual void set_system_delay(double system_delay_s) = 0;
    //! 0: automatic model order from the eigenvalues; otherwise fixed.
    virtual void set_model_order(int order) = 0;
    virtual void set_stages(int stages) = 0;
    virtual void set_attach_csi(bool attach_csi) = 0;
    virtual bool attach_csi() const = 0;

    virtual int num_angles() const = 0;
    virtual int num_delays() const = 0;
    virtual int max_paths() const = 0;
    virtual int smoothing_window() const = 0;
    virtual double system_delay() const = 0;
    virtual int stages() const = 0;
    //! Frames skipped for bad input since start.
    virtual uint64_t num_skipped() const = 0;
    //! Frames estimated since start.
    virtual uint64_t num_estimated() const = 0;
};

} // namespace thrumapper
} // namespace gr

#endif
