/* -*- c++ -*- */
/*
 * SPDX-License-Identifier: GPL-3.0-or-later
 */
#include "angles.h"
#include <gnuradio/io_signature.h>
#include <gnuradio/thrumapper/projection.h>
#include <gnuradio/thrumapper/projection_canceller.h>
#include <atomic>
#include <cmath>
#include <mutex>

namespace gr {
namespace thrumapper {

class projection_canceller_impl : public projection_canceller
{
    const int d_M, d_N;
    mutable std::mutex d_mutex; // guards d_proj: messages and setters come from other threads
    path_projector d_proj;
    std::vector<gr_complex> d_weights; // the direct path's weights outside tagged frames
    const std::vector<gr_complex> d_radar_weights; // ...until weights are set
    const pmt::pmt_t k_tx_weights = pmt::mp("tx_weights");
    const pmt::pmt_t k_direct_path_weights = pmt::mp("direct_path_weights");
    std::atomic<uint64_t> d_skipped{ 0 };
    std::atomic<uint64_t> d_bad_messages{ 0 };

    void bad_message(const std::string& why)
    {
        d_bad_messages++;
        d_logger->warn("message ignored ({:d} so far): {:s}", uint64_t(d_bad_messages), why);
    }

    static bool number(const pmt::pmt_t& v, double& out)
    {
        if (pmt::is_real(v) || pmt::is_integer(v) || pmt::is_uint64(v)) {
            out = pmt::to_double(v);
            return std::isfinite(out);
        }
        return false;
    }

    void handle_paths(const pmt::pmt_t& msg)
    {
        if (!pmt::is_dict(msg))
            return bad_message("\"paths\" wants a dict with \"paths\" or \"clear\"");
        if (pmt::dict_has_key(msg, pmt::mp("clear"))) {
            std::lock_guard<std::mutex> lock(d_mutex);
            d_proj.set_paths({}, {});
            return;
        }
        if (!pmt::dict_has_key(msg, pmt::mp("paths")))
            return bad_message("the dict has no \"paths\" key");
        const pmt::pmt_t paths = pmt::dict_ref(msg, pmt::mp("paths"), pmt::PMT_NIL);
        std::vector<pmt::pmt_t> items;
        if (pmt::is_vector(paths)) {
            for (size_t i = 0; i < pmt::length(paths); i++)
                items.push_back(pmt::vector_ref(paths, i));
        } else if (pmt::is_pair(paths) || pmt::is_null(paths)) { // a list; nil is the empty one
            for (pmt::pmt_t p = paths; pmt::is_pair(p); p = pmt::cdr(p))
                items.push_back(pmt::car(p));
        } else {
            return bad_message("\"paths\" must be a vector or list of dicts");
        }
        std::vector<double> aoa, delay;
        for (size_t i = 0; i < items.size(); i++) {
            double a, d;
            if (!pmt::is_dict(items[i]) ||
                !number(pmt::dict_ref(items[i], pmt::mp("angle_deg"), pmt::PMT_NIL), a) ||
                !number(pmt::dict_ref(items[i], pmt::mp("delay_s"), pmt::PMT_NIL), d))
                return bad_message("path " + std::to_string(i) +
                                   " needs finite \"angle_deg\" and \"delay_s\"");
            aoa.push_back(a * M_PI / 180.0);
            delay.push_back(d);
        }
        try {
            std::lock_guard<std::mutex> lock(d_mutex);
            d_proj.set_paths(aoa, delay);
        } catch (const std::exception& e) {
            bad_message(e.what());
        }
    }

    void handle_weights(const pmt::pmt_t& msg)
    {
        pmt::pmt_t v = msg;
        if (pmt::is_dict(msg))
            v = pmt::dict_ref(msg, pmt::mp("weights"), pmt::PMT_NIL);
        std::vector<gr_complex> w;
        if (pmt::is_c32vector(v))
            w = pmt::c32vector_elements(v);
        else if (pmt::is_c64vector(v))
            for (const auto& x : pmt::c64vector_elements(v))
                w.emplace_back(float(x.real()), float(x.imag()));
        else
            return bad_message("\"weights\" wants a c32vector or a dict with \"weights\"");
        try {
            std::lock_guard<std::mutex> lock(d_mutex);
            d_proj.set_direct_path(d_proj.cancels_direct_path(), w);
            d_weights = w;
        } catch (const std::exception& e) {
            bad_message(e.what());
        }
    }

public:
    projection_canceller_impl(radar_description::sptr radar,
                              const std::vector<double>& aoa_deg,
                              const std::vector<double>& delay_s,
                              bool cancel_direct,
                              double system_delay_s)
        : gr::block("projection_canceller",
                    gr::io_signature::make(1, 1, sizeof(gr_complex) * (radar ? radar->num_rx() * radar->num_subcarriers() : 1)),
                    gr::io_signature::make(1, 1, sizeof(gr_complex) * (radar ? radar->num_rx() * radar->num_subcarriers() : 1))),
          d_M(radar ? radar->num_rx() : 0),
          d_N(radar ? radar->num_subcarriers() : 0),
          d_proj(radar),
          d_radar_weights(radar ? radar->tx_weights() : std::vector<gr_complex>{})
    {
        d_proj.set_system_delay(system_delay_s);
        d_proj.set_paths(degrees_to_radians(aoa_deg), delay_s);
        d_proj.set_direct_path(cancel_direct);
        message_port_register_in(pmt::mp("paths"));
        set_msg_handler(pmt::mp("paths"), [this](const pmt::pmt_t& m) { handle_paths(m); });
        message_port_register_in(pmt::mp("weights"));
        set_msg_handler(pmt::mp("weights"), [this](const pmt::pmt_t& m) { handle_weights(m); });
        set_tag_propagation_policy(TPP_DONT);
    }

    void forecast(int noutput_items, gr_vector_int& ninput_items_required) override
    {
        ninput_items_required[0] = noutput_items;
    }

    int general_work(int noutput_items,
                     gr_vector_int& ninput_items,
                     gr_vector_const_void_star& input_items,
                     gr_vector_void_star& output_items) override
    {
        const gr_complex* in = static_cast<const gr_complex*>(input_items[0]);
        gr_complex* out = static_cast<gr_complex*>(output_items[0]);
        const size_t len = size_t(d_M) * d_N;
        const int n = std::min(noutput_items, ninput_items[0]);
        int produced = 0;
        std::lock_guard<std::mutex> lock(d_mutex); // updates land between frames
        for (int i = 0; i < n; i++) {
            const gr_complex* frame = in + i * len;
            bool finite = true;
            for (size_t k = 0; k < len && finite; k++)
                finite = std::isfinite(frame[k].real()) && std::isfinite(frame[k].imag());
            if (!finite) {
                d_skipped++;
                d_logger->warn("frame {:d} dropped ({:d} so far): NaN or Inf values",
                               nitems_read(0) + i,
                               uint64_t(d_skipped));
                continue;
            }
            std::vector<tag_t> tags;
            get_tags_in_range(tags, 0, nitems_read(0) + i, nitems_read(0) + i + 1);
            // a "tx_weights" tag (survey_source puts one on frames whose weights differ from
            // the survey's global ones) holds for its frame only
            std::vector<gr_complex> frame_weights;
            for (const auto& t : tags)
                if (pmt::eqv(t.key, k_tx_weights)) {
                    if (pmt::is_c64vector(t.value))
                        for (const auto& x : pmt::c64vector_elements(t.value))
                            frame_weights.emplace_back(float(x.real()), float(x.imag()));
                    else if (pmt::is_c32vector(t.value))
                        frame_weights = pmt::c32vector_elements(t.value);
                }
            if (!frame_weights.empty() && d_proj.cancels_direct_path()) {
                const std::vector<gr_complex> held = d_weights;
                try {
                    d_proj.set_direct_path(true, frame_weights);
                    d_proj.apply(frame, out + produced * len, 1);
                } catch (const std::exception& e) {
                    bad_message(std::string("tx_weights tag: ") + e.what());
                    d_proj.set_direct_path(true, held);
                    d_proj.apply(frame, out + produced * len, 1);
                }
                d_proj.set_direct_path(true, held);
            } else {
                d_proj.apply(frame, out + produced * len, 1);
            }
            for (const auto& t : tags)
                add_item_tag(0, nitems_written(0) + produced, t.key, t.value);
            if (d_proj.cancels_direct_path()) { // what wall_fusion's CSI fits must know
                const auto& used = !frame_weights.empty() ? frame_weights
                                   : !d_weights.empty()   ? d_weights
                                                          : d_radar_weights;
                add_item_tag(0,
                             nitems_written(0) + produced,
                             k_direct_path_weights,
                             pmt::init_c32vector(used.size(), used.data()));
            }
            produced++;
        }
        consume_each(n);
        return produced;
    }

    void set_paths(const std::vector<double>& aoa_deg, const std::vector<double>& delay_s) override
    {
        std::lock_guard<std::mutex> lock(d_mutex);
        d_proj.set_paths(degrees_to_radians(aoa_deg), delay_s);
    }
    void set_cancel_direct(bool cancel_direct) override
    {
        std::lock_guard<std::mutex> lock(d_mutex);
        d_proj.set_direct_path(cancel_direct, d_weights);
    }
    void set_system_delay(double system_delay_s) override
    {
        std::lock_guard<std::mutex> lock(d_mutex);
        d_proj.set_system_delay(system_delay_s);
    }
    void set_tx_weights(const std::vector<gr_complex>& weights) override
    {
        std::lock_guard<std::mutex> lock(d_mutex);
        d_proj.set_direct_path(d_proj.cancels_direct_path(), weights);
        d_weights = weights;
    }
    int rank() const override
    {
        std::lock_guard<std::mutex> lock(d_mutex);
        return d_proj.rank();
    }
    uint64_t num_skipped() const override { return d_skipped; }
    uint64_t num_bad_messages() const override { return d_bad_messages; }
};

projection_canceller::sptr projection_canceller::make(radar_description::sptr radar,
                                                      const std::vector<double>& aoa_deg,
                                                      const std::vector<double>& delay_s,
                                                      bool cancel_direct,
                                                      double system_delay_s)
{
    if (!radar)
        throw std::invalid_argument("projection_canceller: a radar description is required");
    return gnuradio::make_block_sptr<projection_canceller_impl>(
        radar, aoa_deg, delay_s, cancel_direct, system_delay_s);
}

} // namespace thrumapper
} // namespace gr
