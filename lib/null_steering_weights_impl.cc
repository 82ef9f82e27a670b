/* -*- c++ -*- */
/*
 * SPDX-License-Identifier: GPL-3.0-or-later
 */
#include "angles.h"
#include <gnuradio/io_signature.h>
#include <gnuradio/thrumapper/null_steering.h>
#include <gnuradio/thrumapper/null_steering_weights.h>
#include <chrono>
#include <cmath>
#include <condition_variable>
#include <mutex>

namespace gr {
namespace thrumapper {

class null_steering_weights_impl : public null_steering_weights
{
    null_steering d_design;
    const int d_num_angles;
    const std::chrono::duration<double> d_period;
    mutable std::mutex d_mutex;
    std::condition_variable d_cv;
    struct design_spec {
        double main_lobe_deg;
        bool null_receiver;
        std::vector<double> null_angles_deg;
    };
    design_spec d_spec;
    std::vector<gr_complex> d_weights;
    std::vector<float> d_pattern_db;
    bool d_changed = true;
    bool d_stopping = false;
    std::chrono::steady_clock::time_point d_last_output;
    const pmt::pmt_t d_port;

    // Design the weights and their pattern; callers hold no lock (the design may throw,
    // leaving the current weights in place).
    void redesign(const design_spec& spec)
    {
        const std::vector<gr_complex> w = d_design.design(
            spec.main_lobe_deg * M_PI / 180.0, degrees_to_radians(spec.null_angles_deg), spec.null_receiver);
        std::vector<double> angles(d_num_angles), freqs;
        for (int i = 0; i < d_num_angles; i++)
            angles[i] = 2 * M_PI * i / d_num_angles;
        const auto& off = d_design.radar()->subcarrier_offsets_hz();
        for (int i = 0; i < 16; i++)
            freqs.push_back(d_design.radar()->carrier_hz() + off[i * (off.size() - 1) / 15]);
        const Eigen::MatrixXd g = d_design.beam_pattern_db(w, angles, freqs);
        std::vector<float> pattern(d_num_angles);
        for (int j = 0; j < d_num_angles; j++)
            pattern[j] = float(10 * std::log10((g.col(j).array() / 10 * std::log(10.0)).exp().mean()));
        {
            std::lock_guard<std::mutex> lock(d_mutex);
            d_spec = spec;
            d_weights = w;
            d_pattern_db = pattern;
            d_changed = true;
        }
        d_cv.notify_all();
        publish();
    }

    void publish()
    {
        pmt::pmt_t msg = pmt::make_dict();
        {
            std::lock_guard<std::mutex> lock(d_mutex);
            msg = pmt::dict_add(msg, pmt::mp("weights"), pmt::init_c32vector(d_weights.size(), d_weights));
            msg = pmt::dict_add(msg, pmt::mp("main_lobe_deg"), pmt::from_double(d_spec.main_lobe_deg));
            msg = pmt::dict_add(msg, pmt::mp("null_angles_deg"),
                                pmt::init_f64vector(d_spec.null_angles_deg.size(), d_spec.null_angles_deg));
            msg = pmt::dict_add(msg, pmt::mp("null_receiver"), pmt::from_bool(d_spec.null_receiver));
            msg = pmt::dict_add(msg, pmt::mp("coupling_db"), pmt::from_double(d_design.coupling_db(d_weights)));
        }
        message_port_pub(d_port, msg);
    }

public:
    null_steering_weights_impl(radar_description::sptr radar,
                               double main_lobe_deg,
                               bool null_receiver,
                               const std::vector<double>& null_angles_deg,
                               int num_angles,
                               double update_period_s)
        : gr::sync_block("null_steering_weights",
                         gr::io_signature::make(0, 0, 0),
                         gr::io_signature::make(0, 1, sizeof(float) * std::max(num_angles, 1))),
          d_design(radar),
          d_num_angles(num_angles),
          d_period(update_period_s),
          d_port(pmt::mp("weights"))
    {
        if (num_angles < 3)
            throw std::invalid_argument("null_steering_weights: num_angles must be at least 3");
        if (!(update_period_s > 0) || !std::isfinite(update_period_s))
            throw std::invalid_argument("null_steering_weights: update_period_s must be positive");
        message_port_register_out(d_port);
        redesign({ main_lobe_deg, null_receiver, null_angles_deg });
    }

    bool start() override
    {
        {
            std::lock_guard<std::mutex> lock(d_mutex);
            d_stopping = false;
            d_changed = true;
        }
        publish();
        return gr::sync_block::start();
    }

    bool stop() override
    {
        {
            std::lock_guard<std::mutex> lock(d_mutex);
            d_stopping = true;
        }
        d_cv.notify_all();
        return gr::sync_block::stop();
    }

    int work(int noutput_items, gr_vector_const_void_star&, gr_vector_void_star& output_items) override
    {
        std::unique_lock<std::mutex> lock(d_mutex);
        // a pattern when the weights change, else one per period: wait, don't spin
        const auto due = d_last_output + std::chrono::duration_cast<std::chrono::steady_clock::duration>(d_period);
        d_cv.wait_until(lock, due, [this] { return d_changed || d_stopping; });
        if (d_stopping)
            return WORK_DONE;
        if (!d_changed && std::chrono::steady_clock::now() < due)
            return 0;
        std::copy(d_pattern_db.begin(), d_pattern_db.end(), static_cast<float*>(output_items[0]));
        d_changed = false;
        d_last_output = std::chrono::steady_clock::now();
        (void)noutput_items;
        return 1;
    }

    // A copy of the current spec with one field changed: a failed design leaves it as it was.
    design_spec current_spec() const
    {
        std::lock_guard<std::mutex> lock(d_mutex);
        return d_spec;
    }

    void set_main_lobe(double main_lobe_deg) override
    {
        design_spec spec = current_spec();
        spec.main_lobe_deg = main_lobe_deg;
        redesign(spec);
    }

    void set_null_angles(const std::vector<double>& null_angles_deg) override
    {
        design_spec spec = current_spec();
        spec.null_angles_deg = null_angles_deg;
        redesign(spec);
    }

    void set_null_receiver(bool null_receiver) override
    {
        design_spec spec = current_spec();
        spec.null_receiver = null_receiver;
        redesign(spec);
    }

    std::vector<gr_complex> weights() const override
    {
        std::lock_guard<std::mutex> lock(d_mutex);
        return d_weights;
    }

    double coupling_db() const override
    {
        std::lock_guard<std::mutex> lock(d_mutex);
        return d_design.coupling_db(d_weights);
    }

    double expected_coupling_db(double phase_error_deg) const override
    {
        std::lock_guard<std::mutex> lock(d_mutex);
        return d_design.expected_coupling_db(d_weights, phase_error_deg * M_PI / 180.0);
    }
};

null_steering_weights::sptr null_steering_weights::make(radar_description::sptr radar,
                                                        double main_lobe_deg,
                                                        bool null_receiver,
                                                        const std::vector<double>& null_angles_deg,
                                                        int num_angles,
                                                        double update_period_s)
{
    return gnuradio::make_block_sptr<null_steering_weights_impl>(
        radar, main_lobe_deg, null_receiver, null_angles_deg, num_angles, update_period_s);
}

} // namespace thrumapper
} // namespace gr
