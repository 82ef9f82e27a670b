/* -*- c++ -*- */
/*
 * SPDX-License-Identifier: GPL-3.0-or-later
 */
#include "ofdm_sounder_impl.h"
#include <gnuradio/io_signature.h>
#include <cmath>
#include <cstring>

namespace gr {
namespace thrumapper {

namespace {
const pmt::pmt_t k_sob = pmt::mp("tx_sob");
const pmt::pmt_t k_eob = pmt::mp("tx_eob");
const pmt::pmt_t k_time = pmt::mp("tx_time");
const pmt::pmt_t k_index = pmt::mp("frame_index");
const pmt::pmt_t k_weights = pmt::mp("tx_weights");

ofdm_sounding::sptr require(ofdm_sounding::sptr s)
{
    if (!s)
        throw std::invalid_argument("ofdm_sounder: a sounding description is required");
    return s;
}
} // namespace

ofdm_sounder::sptr ofdm_sounder::make(ofdm_sounding::sptr sounding,
                                      const std::vector<gr_complex>& weights,
                                      double start_time_s)
{
    return gnuradio::make_block_sptr<ofdm_sounder_impl>(sounding, weights, start_time_s);
}

ofdm_sounder_impl::ofdm_sounder_impl(ofdm_sounding::sptr sounding,
                                     const std::vector<gr_complex>& weights,
                                     double start_time_s)
    : gr::sync_block("ofdm_sounder",
                     gr::io_signature::make(0, 0, 0),
                     gr::io_signature::make(require(sounding)->num_tx(),
                                            sounding->num_tx(),
                                            sizeof(gr_complex))),
      d_sounding(sounding),
      d_K(sounding->num_tx()),
      d_P(sounding->frame_len()),
      d_start_time_s(start_time_s),
      d_frame(d_K, std::vector<gr_complex>(d_P)),
      d_srcid(pmt::mp(alias()))
{
    if (!std::isfinite(start_time_s))
        throw std::invalid_argument("ofdm_sounder: start_time_s must be finite");
    d_pending = check_weights(weights.empty() ? sounding->radar()->tx_weights() : weights);
    d_active = d_pending;
    message_port_register_in(pmt::mp("weights"));
    set_msg_handler(pmt::mp("weights"), [this](const pmt::pmt_t& msg) { handle_weights(msg); });
}

std::vector<gr_complex> ofdm_sounder_impl::check_weights(const std::vector<gr_complex>& w) const
{
    if (static_cast<int>(w.size()) != d_K)
        throw std::invalid_argument("ofdm_sounder: expected K=" + std::to_string(d_K) +
                                    " weights, got " + std::to_string(w.size()));
    for (const auto& v : w)
        if (!std::isfinite(v.real()) || !std::isfinite(v.imag()))
            throw std::invalid_argument("ofdm_sounder: weights must be finite");
    return w;
}

void ofdm_sounder_impl::handle_weights(const pmt::pmt_t& msg)
{
    pmt::pmt_t v = msg;
    if (pmt::is_dict(msg))
        v = pmt::dict_ref(msg, pmt::mp("weights"), pmt::PMT_NIL);
    std::vector<gr_complex> w;
    if (pmt::is_c32vector(v)) {
        w = pmt::c32vector_elements(v);
    } else if (pmt::is_c64vector(v)) {
        for (const auto& x : pmt::c64vector_elements(v))
            w.emplace_back(float(x.real()), float(x.imag()));
    } else {
        d_rejected++;
        d_logger->warn("ignoring a weights message without a complex vector ({:d} so far): {:s}",
                       uint64_t(d_rejected),
                       pmt::write_string(msg).substr(0, 200));
        return;
    }
    try {
        set_weights(w);
    } catch (const std::exception& e) {
        d_rejected++;
        d_logger->warn("ignoring a weights message ({:d} so far): {:s}",
                       uint64_t(d_rejected),
                       e.what());
    }
}

void ofdm_sounder_impl::set_weights(const std::vector<gr_complex>& weights)
{
    auto w = check_weights(weights);
    std::lock_guard<std::mutex> lock(d_mutex);
    d_pending = std::move(w);
    d_changed = true;
}

std::vector<gr_complex> ofdm_sounder_impl::weights() const
{
    std::lock_guard<std::mutex> lock(d_mutex);
    return d_pending;
}

void ofdm_sounder_impl::start_frame(uint64_t abs_offset)
{
    bool changed;
    {
        std::lock_guard<std::mutex> lock(d_mutex);
        changed = d_changed;
        if (changed)
            d_active = d_pending;
        d_changed = false;
    }
    if (changed || d_frame_index == 0)
        for (int k = 0; k < d_K; k++)
            d_sounding->frame_samples(k, d_active, d_frame[k].data());

    std::vector<std::complex<double>> wide(d_active.begin(), d_active.end());
    for (int k = 0; k < d_K; k++) {
        add_item_tag(k, abs_offset, k_sob, pmt::PMT_T, d_srcid);
        add_item_tag(k, abs_offset + d_P - 1, k_eob, pmt::PMT_T, d_srcid);
        add_item_tag(k, abs_offset, k_index, pmt::from_uint64(d_frame_index), d_srcid);
        if (d_start_time_s >= 0) {
            const double whole0 = std::floor(d_start_time_s);
            const double t = (d_start_time_s - whole0) +
                             double(d_frame_index) * double(d_P) / d_sounding->sample_rate_hz();
            const double whole = std::floor(t);
            add_item_tag(k,
                         abs_offset,
                         k_time,
                         pmt::make_tuple(pmt::from_uint64(uint64_t(whole0 + whole)),
                                         pmt::from_double(t - whole)),
                         d_srcid);
        }
        if (changed || d_frame_index == 0)
            add_item_tag(k, abs_offset, k_weights, pmt::init_c64vector(d_K, wide), d_srcid);
    }
    d_frames++;
}

int ofdm_sounder_impl::work(int noutput_items,
                            gr_vector_const_void_star&,
                            gr_vector_void_star& output_items)
{
    int done = 0;
    while (done < noutput_items) {
        if (d_pos == 0)
            start_frame(nitems_written(0) + done);
        const int count = std::min(noutput_items - done, d_P - d_pos);
        for (int k = 0; k < d_K; k++)
            std::memcpy(static_cast<gr_complex*>(output_items[k]) + done,
                        d_frame[k].data() + d_pos,
                        sizeof(gr_complex) * count);
        done += count;
        d_pos += count;
        if (d_pos == d_P) {
            d_pos = 0;
            d_frame_index++;
        }
    }
    return done;
}

} // namespace thrumapper
} // namespace gr
