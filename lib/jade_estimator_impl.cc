/* -*- c++ -*- */
/*
 * SPDX-License-Identifier: GPL-3.0-or-later
 */
#include "jade_estimator_impl.h"
#include <gnuradio/io_signature.h>
#include <cmath>
#include <cstring>

namespace gr {
namespace thrumapper {

namespace {
const pmt::pmt_t k_frame_index = pmt::mp("frame_index");
const pmt::pmt_t k_rx_time = pmt::mp("rx_time");
const pmt::pmt_t k_pose = pmt::mp("pose");
const pmt::pmt_t k_tx_weights = pmt::mp("tx_weights");
const pmt::pmt_t k_direct_path_weights = pmt::mp("direct_path_weights");

pmt::pmt_t vector_of(const std::vector<pmt::pmt_t>& items)
{
    pmt::pmt_t v = pmt::make_vector(items.size(), pmt::PMT_NIL);
    for (size_t i = 0; i < items.size(); i++)
        pmt::vector_set(v, i, items[i]);
    return v;
}

std::vector<double> delay_grid(int count, double min_s, double max_s)
{
    if (count < 2)
        throw std::invalid_argument("jade_estimator: num_delays must be at least 2");
    if (!(max_s > min_s) || !std::isfinite(min_s) || !std::isfinite(max_s))
        throw std::invalid_argument("jade_estimator: delay_max_s must be above delay_min_s");
    return jade::linear_grid(min_s, max_s, count);
}
} // namespace

jade_estimator::sptr jade_estimator::make(radar_description::sptr radar,
                                          int num_angles,
                                          double angle_min_deg,
                                          double angle_max_deg,
                                          int num_delays,
                                          double delay_min_s,
                                          double delay_max_s,
                                          int max_paths,
                                          int smoothing_window,
                                          double system_delay_s,
                                          int stages,
                                          bool attach_csi)
{
    return gnuradio::make_block_sptr<jade_estimator_impl>(radar,
                                                          num_angles,
                                                          angle_min_deg,
                                                          angle_max_deg,
                                                          num_delays,
                                                          delay_min_s,
                                                          delay_max_s,
                                                          max_paths,
                                                          smoothing_window,
                                                          system_delay_s,
                                                          stages,
                                                          attach_csi);
}

std::vector<double> jade_estimator_impl::angle_grid(int count, double min_deg, double max_deg)
{
    if (count < 3)
        throw std::invalid_argument("jade_estimator: num_angles must be at least 3");
    if (!(max_deg > min_deg) || !std::isfinite(min_deg) || !std::isfinite(max_deg))
        throw std::invalid_argument("jade_estimator: angle_max_deg must be above angle_min_deg");
    std::vector<double> g(count);
    // a span of a whole turn excludes its end, which is its start again
    const bool full = std::abs(max_deg - min_deg - 360.0) < 1e-9;
    const double step = (max_deg - min_deg) / (full ? count : count - 1);
    for (int i = 0; i < count; i++)
        g[i] = (min_deg + i * step) * M_PI / 180.0;
    return g;
}

static radar_description::sptr require_radar(radar_description::sptr radar)
{
    if (!radar)
        throw std::invalid_argument("jade_estimator: a radar description is required");
    return radar;
}

jade_estimator_impl::jade_estimator_impl(radar_description::sptr radar,
                                         int num_angles,
                                         double angle_min_deg,
                                         double angle_max_deg,
                                         int num_delays,
                                         double delay_min_s,
                                         double delay_max_s,
                                         int max_paths,
                                         int smoothing_window,
                                         double system_delay_s,
                                         int stages,
                                         bool attach_csi)
    : gr::block("jade_estimator",
                gr::io_signature::make(1, 1, sizeof(gr_complex) * require_radar(radar)->num_rx() *
                                                 radar->num_subcarriers()),
                gr::io_signature::make(1, 1, sizeof(float) * num_angles * num_delays)),
      d_radar(radar),
      d_M(radar->num_rx()),
      d_N(radar->num_subcarriers()),
      d_num_angles(num_angles),
      d_num_delays(num_delays),
      d_jade(radar,
             angle_grid(num_angles, angle_min_deg, angle_max_deg),
             delay_grid(num_delays, delay_min_s, delay_max_s),
             smoothing_window,
             max_paths),
      d_port(pmt::mp("paths"))
{
    d_jade.set_system_delay(system_delay_s);
    d_jade.set_stages(stages);
    d_attach_csi = attach_csi;
    message_port_register_out(d_port);
    set_tag_propagation_policy(TPP_DONT); // tags are re-attached to the matching output item
}

void jade_estimator_impl::forecast(int noutput_items, gr_vector_int& ninput_items_required)
{
    ninput_items_required[0] = noutput_items;
}

int jade_estimator_impl::general_work(int noutput_items,
                                      gr_vector_int& ninput_items,
                                      gr_vector_const_void_star& input_items,
                                      gr_vector_void_star& output_items)
{
    const gr_complex* in = static_cast<const gr_complex*>(input_items[0]);
    float* out = static_cast<float*>(output_items[0]);
    const int n_in = std::min(noutput_items, ninput_items[0]);
    const size_t spectrum_len = size_t(d_num_angles) * d_num_delays;
    int produced = 0;

    for (int i = 0; i < n_in; i++) {
        const uint64_t abs_in = nitems_read(0) + i;
        std::vector<tag_t> tags;
        get_tags_in_range(tags, 0, abs_in, abs_in + 1);
        uint64_t frame_index = d_frame_counter;
        pmt::pmt_t rx_time = pmt::PMT_NIL, pose = pmt::PMT_NIL, tx_weights = pmt::PMT_NIL,
                   direct_weights = pmt::PMT_NIL;
        for (const auto& t : tags) {
            if (pmt::eqv(t.key, k_frame_index) && (pmt::is_integer(t.value) || pmt::is_uint64(t.value)))
                frame_index = pmt::to_uint64(t.value);
            else if (pmt::eqv(t.key, k_rx_time))
                rx_time = t.value;
            else if (pmt::eqv(t.key, k_pose))
                pose = t.value;
            else if (pmt::eqv(t.key, k_tx_weights))
                tx_weights = t.value;
            else if (pmt::eqv(t.key, k_direct_path_weights))
                direct_weights = t.value;
        }

        // untagged frames count on from the last index seen, skipped frames included
        d_frame_counter = frame_index + 1;
        std::vector<jade_path> paths;
        int order = 0;
        double system_delay_s = 0.0;
        try {
            std::lock_guard<std::mutex> lock(d_mutex);
            paths = d_jade.estimate(in + size_t(i) * d_M * d_N, 1);
            order = d_jade.model_order();
            system_delay_s = d_jade.system_delay();
            std::memcpy(out + produced * spectrum_len,
                        d_jade.spectrum_db().data(),
                        spectrum_len * sizeof(float));
        } catch (const std::exception& e) {
            d_skipped++;
            d_logger->warn("frame {:d} skipped ({:d} so far): {:s}",
                           frame_index,
                           uint64_t(d_skipped),
                           e.what());
            continue;
        }
        d_estimated++;

        const uint64_t abs_out = nitems_written(0) + produced;
        for (const auto& t : tags)
            add_item_tag(0, abs_out, t.key, t.value);
        produced++;

        std::vector<pmt::pmt_t> items;
        for (const auto& q : paths) {
            pmt::pmt_t p = pmt::make_dict();
            p = pmt::dict_add(p, pmt::mp("angle_deg"), pmt::from_double(q.aoa_rad * 180.0 / M_PI));
            p = pmt::dict_add(p, pmt::mp("delay_s"), pmt::from_double(q.delay_s));
            p = pmt::dict_add(p, pmt::mp("power"), pmt::from_double(q.power));
            p = pmt::dict_add(p, pmt::mp("spectrum_db"), pmt::from_double(q.spectrum_db));
            p = pmt::dict_add(p, pmt::mp("stage"), pmt::from_long(q.stage));
            items.push_back(p);
        }
        pmt::pmt_t msg = pmt::make_dict();
        msg = pmt::dict_add(msg, k_frame_index, pmt::from_uint64(frame_index));
        if (!pmt::is_null(rx_time))
            msg = pmt::dict_add(msg, k_rx_time, rx_time);
        if (!pmt::is_null(pose))
            msg = pmt::dict_add(msg, k_pose, pose);
        msg = pmt::dict_add(msg, pmt::mp("model_order"), pmt::from_long(order));
        msg = pmt::dict_add(msg, pmt::mp("paths"), vector_of(items));
        if (d_attach_csi) {
            const gr_complex* frame = in + size_t(i) * d_M * d_N;
            msg = pmt::dict_add(msg, pmt::mp("csi"), pmt::init_c32vector(size_t(d_M) * d_N, frame));
            msg = pmt::dict_add(msg, pmt::mp("system_delay_s"), pmt::from_double(system_delay_s));
            const pmt::pmt_t weights = pmt::is_null(tx_weights) ? direct_weights : tx_weights;
            if (!pmt::is_null(weights))
                msg = pmt::dict_add(msg, k_tx_weights, weights);
            msg = pmt::dict_add(msg, pmt::mp("direct_path_cancelled"), pmt::from_bool(!pmt::is_null(direct_weights)));
        }
        message_port_pub(d_port, msg);
    }
    consume_each(n_in);
    return produced;
}

void jade_estimator_impl::set_angle_span(double angle_min_deg, double angle_max_deg)
{
    auto g = angle_grid(d_num_angles, angle_min_deg, angle_max_deg);
    std::lock_guard<std::mutex> lock(d_mutex);
    d_jade.set_angle_grid(g);
}

void jade_estimator_impl::set_delay_span(double delay_min_s, double delay_max_s)
{
    auto g = delay_grid(d_num_delays, delay_min_s, delay_max_s);
    std::lock_guard<std::mutex> lock(d_mutex);
    d_jade.set_delay_grid(g);
}

void jade_estimator_impl::set_max_paths(int max_paths)
{
    std::lock_guard<std::mutex> lock(d_mutex);
    d_jade.set_max_paths(max_paths);
}

void jade_estimator_impl::set_smoothing_window(int subcarriers)
{
    std::lock_guard<std::mutex> lock(d_mutex);
    d_jade.set_smoothing_window(subcarriers);
}

void jade_estimator_impl::set_system_delay(double system_delay_s)
{
    std::lock_guard<std::mutex> lock(d_mutex);
    d_jade.set_system_delay(system_delay_s);
}

void jade_estimator_impl::set_model_order(int order)
{
    std::lock_guard<std::mutex> lock(d_mutex);
    d_jade.set_model_order(order);
}

void jade_estimator_impl::set_stages(int stages)
{
    std::lock_guard<std::mutex> lock(d_mutex);
    d_jade.set_stages(stages);
}

int jade_estimator_impl::stages() const
{
    std::lock_guard<std::mutex> lock(d_mutex);
    return d_jade.stages();
}

int jade_estimator_impl::max_paths() const
{
    std::lock_guard<std::mutex> lock(d_mutex);
    return d_jade.max_paths();
}

int jade_estimator_impl::smoothing_window() const
{
    std::lock_guard<std::mutex> lock(d_mutex);
    return d_jade.smoothing_window();
}

double jade_estimator_impl::system_delay() const
{
    std::lock_guard<std::mutex> lock(d_mutex);
    return d_jade.system_delay();
}

} // namespace thrumapper
} // namespace gr
