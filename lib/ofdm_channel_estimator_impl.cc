/* -*- c++ -*- */
/*
 * SPDX-License-Identifier: GPL-3.0-or-later
 */
#include "ofdm_channel_estimator_impl.h"
#include <gnuradio/io_signature.h>
#include <algorithm>
#include <cmath>
#include <cstring>

namespace gr {
namespace thrumapper {

namespace {
const pmt::pmt_t k_frame_index = pmt::mp("frame_index");
const pmt::pmt_t k_rx_time = pmt::mp("rx_time");
const pmt::pmt_t k_timing = pmt::mp("timing_offset");
const pmt::pmt_t k_metric = pmt::mp("preamble_metric");
const pmt::pmt_t k_pose = pmt::mp("pose");
const pmt::pmt_t k_rx_freq = pmt::mp("rx_freq");
const pmt::pmt_t k_frame_type = pmt::mp("frame_type");
const pmt::pmt_t k_tx_element = pmt::mp("tx_element");
const pmt::pmt_t k_tx_weights = pmt::mp("tx_weights");
const pmt::pmt_t k_mode = pmt::mp("sounding_mode");

ofdm_sounding::sptr require(ofdm_sounding::sptr s)
{
    if (!s)
        throw std::invalid_argument("ofdm_channel_estimator: a sounding description is required");
    return s;
}

bool parse_time(const pmt::pmt_t& v, uint64_t& secs, double& frac)
{
    if (!pmt::is_tuple(v) || pmt::length(v) != 2)
        return false;
    const pmt::pmt_t s = pmt::tuple_ref(v, 0), f = pmt::tuple_ref(v, 1);
    if (pmt::is_uint64(s))
        secs = pmt::to_uint64(s);
    else if (pmt::is_integer(s) && pmt::to_long(s) >= 0)
        secs = uint64_t(pmt::to_long(s));
    else
        return false;
    if (!pmt::is_real(f) && !pmt::is_integer(f))
        return false;
    frac = pmt::to_double(f);
    return std::isfinite(frac);
}
} // namespace

ofdm_channel_estimator::sptr ofdm_channel_estimator::make(ofdm_sounding::sptr sounding,
                                                          int64_t frame_offset,
                                                          int search_window,
                                                          int timing_backoff,
                                                          double detection_threshold)
{
    return gnuradio::make_block_sptr<ofdm_channel_estimator_impl>(
        sounding, frame_offset, search_window, timing_backoff, detection_threshold);
}

ofdm_channel_estimator_impl::ofdm_channel_estimator_impl(ofdm_sounding::sptr sounding,
                                                         int64_t frame_offset,
                                                         int search_window,
                                                         int timing_backoff,
                                                         double detection_threshold)
    : gr::block("ofdm_channel_estimator",
                gr::io_signature::make(require(sounding)->num_rx(),
                                       sounding->num_rx(),
                                       sizeof(gr_complex)),
                gr::io_signature::make(1,
                                       1,
                                       sizeof(gr_complex) * sounding->num_rx() *
                                           sounding->num_subcarriers())),
      d_sounding(sounding),
      d_M(sounding->num_rx()),
      d_N(sounding->num_subcarriers()),
      d_P(sounding->frame_len()),
      d_ipf(sounding->items_per_frame()),
      d_W(search_window < 0 ? sounding->cp_len() : search_window),
      d_backoff(timing_backoff < 0 ? sounding->cp_len() / 4 : timing_backoff),
      d_demod(sounding, d_W, d_backoff, detection_threshold),
      d_threshold(detection_threshold),
      d_span(d_demod.span()),
      d_grid(frame_offset),
      d_scratch(d_M, std::vector<gr_complex>(d_span)),
      d_ptrs(d_M),
      d_srcid(pmt::mp(alias()))
{
    if (frame_offset < -1)
        throw std::invalid_argument("ofdm_channel_estimator: frame_offset must be >= 0, or -1 "
                                    "to acquire the frame timing from the first preamble");
    if (frame_offset == -1) {
        d_grid = 0;
        d_acquire = std::make_unique<ofdm_demodulator>(
            sounding, d_P / 2, d_backoff, detection_threshold);
    }
    if (d_W >= d_P / 2)
        throw std::invalid_argument("ofdm_channel_estimator: search_window must be below half "
                                    "a frame (" +
                                    std::to_string(d_P / 2) + " samples)");
    for (int m = 0; m < d_M; m++)
        d_ptrs[m] = d_scratch[m].data();
    set_tag_propagation_policy(TPP_DONT);
    set_output_multiple(d_ipf);
    set_relative_rate(uint64_t(d_ipf), uint64_t(d_P));
}

void ofdm_channel_estimator_impl::set_detection_threshold(double threshold)
{
    if (!(threshold > 0.0 && threshold < 1.0))
        throw std::invalid_argument("ofdm_channel_estimator: detection_threshold must be in (0, 1)");
    d_threshold = threshold;
}

void ofdm_channel_estimator_impl::forecast(int noutput_items, gr_vector_int& required)
{
    const int frames = std::max(1, (noutput_items + d_ipf - 1) / d_ipf);
    for (auto& r : required) // the next frame's span, and one frame length per frame after it
        r = (frames - 1) * d_P + d_span;
}

pmt::pmt_t ofdm_channel_estimator_impl::time_of(int64_t offset) const
{
    const double rel = d_anchor_frac + double(offset - int64_t(d_anchor_offset)) /
                                           d_sounding->sample_rate_hz();
    const double whole = std::floor(rel);
    return pmt::make_tuple(pmt::from_uint64(uint64_t(int64_t(d_anchor_secs) + int64_t(whole))),
                           pmt::from_double(rel - whole));
}

void ofdm_channel_estimator_impl::apply_time_tag(const tag_t& tag)
{
    uint64_t secs;
    double frac;
    if (!parse_time(tag.value, secs, frac)) {
        d_logger->warn("ignoring a malformed rx_time tag at sample {:d}", tag.offset);
        return;
    }
    if (d_have_time) {
        const double fs = d_sounding->sample_rate_hz();
        const double elapsed_s = double(int64_t(secs) - int64_t(d_anchor_secs)) + (frac - d_anchor_frac);
        const double lost = elapsed_s * fs - double(int64_t(tag.offset) - int64_t(d_anchor_offset));
        if (std::abs(lost) >= 0.5) {
            const int64_t samples = std::llround(lost);
            d_grid -= samples; // later frames sit `samples` earlier in the stream
            d_last_discontinuity = int64_t(tag.offset);
            d_discontinuities++;
            d_logger->warn("stream discontinuity at sample {:d}: {:d} samples lost (overflow); "
                           "frame grid moved",
                           tag.offset,
                           samples);
        }
    }
    d_have_time = true;
    d_anchor_offset = tag.offset;
    d_anchor_secs = secs;
    d_anchor_frac = frac;
}

void ofdm_channel_estimator_impl::skip(std::atomic<uint64_t>& counter,
                                       const char* reason,
                                       double metric)
{
    const uint64_t n = ++counter;
    if (n == 1 || n % 1000 == 0)
        d_logger->warn("frame {:d} skipped: {:s} (preamble metric {:.3f}; {:d} such so far)",
                       d_frame,
                       reason,
                       metric,
                       n);
    d_frame++;
}

int ofdm_channel_estimator_impl::general_work(int noutput_items,
                                              gr_vector_int& ninput_items,
                                              gr_vector_const_void_star& input_items,
                                              gr_vector_void_star& output_items)
{
    const uint64_t R = nitems_read(0);
    int n_avail = ninput_items[0];
    for (int m = 1; m < d_M; m++)
        n_avail = std::min(n_avail, ninput_items[m]);
    const int64_t end = int64_t(R) + n_avail;
    gr_complex* out = static_cast<gr_complex*>(output_items[0]);
    const int burst = d_sounding->burst_len();
    const size_t item = size_t(d_M) * d_N;
    int produced = 0;

    int64_t acquired_up_to = int64_t(R); // acquisition: samples searched without a preamble
    while (d_acquire) {
        // no frame grid yet: search a whole frame period for the first preamble
        const int W = d_acquire->search_window();
        if (int64_t(R) + d_sounding->preamble_len() + 2 * W > end)
            break;
        std::vector<const gr_complex*> ptrs(d_M);
        for (int m = 0; m < d_M; m++)
            ptrs[m] = static_cast<const gr_complex*>(input_items[m]);
        const auto found = d_acquire->detect(ptrs.data(), d_M);
        if (!(found.metric >= d_threshold)) {
            acquired_up_to = int64_t(R) + d_P; // no frame here: look further on
            break;
        }
        d_grid = int64_t(R) + W + found.offset;
        if (d_grid - d_W < int64_t(R)) // too close to what is gone: start at the next frame
            d_grid += d_P;
        d_logger->info("frame timing acquired: the first frame starts at sample {:d}", d_grid);
        d_acquire.reset();
    }

    while (!d_acquire && produced + d_ipf <= noutput_items) {
        const int64_t start = d_grid + int64_t(d_frame) * d_P;
        const int64_t lo = start - d_W, hi = start + burst + d_W;
        if (hi > end)
            break;
        // collect input-0 tags up to the end of this frame's span
        if (int64_t(d_tag_scan) < hi) {
            std::vector<tag_t> tags;
            get_tags_in_range(tags, 0, std::max<uint64_t>(d_tag_scan, R), uint64_t(hi));
            std::sort(tags.begin(), tags.end(), tag_t::offset_compare);
            d_pending.insert(d_pending.end(), tags.begin(), tags.end());
            d_tag_scan = uint64_t(hi);
        }
        // time tags first: an overflow moves the grid
        bool moved = false;
        for (auto it = d_pending.begin(); it != d_pending.end();) {
            if (int64_t(it->offset) < hi && pmt::eqv(it->key, k_rx_time)) {
                const int64_t before = d_grid;
                apply_time_tag(*it);
                it = d_pending.erase(it);
                if (d_grid != before) {
                    moved = true;
                    break;
                }
            } else {
                ++it;
            }
        }
        if (moved)
            continue;
        if (lo < d_last_discontinuity) {
            skip(d_disc_skips, "cut or lost by a stream discontinuity", 0.0);
            continue;
        }
        if (std::max<int64_t>(lo, 0) < int64_t(R)) {
            skip(d_disc_skips, "its samples were already consumed", 0.0);
            continue;
        }
        // the frame's metadata: the latest values tagged before the end of its burst
        for (auto it = d_pending.begin(); it != d_pending.end();) {
            if (int64_t(it->offset) >= start + burst) {
                ++it;
                continue;
            }
            if (pmt::eqv(it->key, k_pose))
                d_pose = it->value;
            else if (pmt::eqv(it->key, k_rx_freq))
                d_rx_freq = it->value;
            else if (pmt::eqv(it->key, k_frame_type))
                d_frame_type = it->value;
            it = d_pending.erase(it);
        }
        // the span, with zeros before the stream's first sample
        const int64_t zeros = std::max<int64_t>(0, -lo);
        for (int m = 0; m < d_M; m++) {
            const gr_complex* in = static_cast<const gr_complex*>(input_items[m]);
            std::fill(d_scratch[m].begin(), d_scratch[m].begin() + zeros, gr_complex(0, 0));
            std::memcpy(d_scratch[m].data() + zeros,
                        in + (lo + zeros - int64_t(R)),
                        sizeof(gr_complex) * size_t(d_span - zeros));
        }
        const auto found = d_demod.detect(d_ptrs.data(), d_M);
        if (!(found.metric >= d_threshold)) {
            skip(d_missing, "preamble missing or damaged", found.metric);
            continue;
        }
        d_demod.estimate(d_ptrs.data(), d_M, found.offset, 0.0, out + produced * item);

        const pmt::pmt_t rx_time = time_of(start);
        for (int s = 0; s < d_ipf; s++) {
            const uint64_t o = nitems_written(0) + produced + s;
            add_item_tag(0, o, k_frame_index, pmt::from_uint64(d_frame), d_srcid);
            add_item_tag(0, o, k_rx_time, rx_time, d_srcid);
            add_item_tag(0, o, k_timing, pmt::from_long(found.offset), d_srcid);
            add_item_tag(0, o, k_metric, pmt::from_double(found.metric), d_srcid);
            if (!pmt::is_null(d_pose))
                add_item_tag(0, o, k_pose, d_pose, d_srcid);
            if (!pmt::is_null(d_rx_freq))
                add_item_tag(0, o, k_rx_freq, d_rx_freq, d_srcid);
            if (!pmt::is_null(d_frame_type))
                add_item_tag(0, o, k_frame_type, d_frame_type, d_srcid);
            if (d_sounding->mode() == sounding_mode::sequential) {
                std::vector<std::complex<double>> unit(d_sounding->num_tx(), 0.0);
                unit[s] = 1.0;
                add_item_tag(0, o, k_tx_element, pmt::from_long(s), d_srcid);
                add_item_tag(0, o, k_tx_weights, pmt::init_c64vector(unit.size(), unit), d_srcid);
            } else if (d_sounding->mode() == sounding_mode::interleaved) {
                add_item_tag(0, o, k_mode, pmt::mp("interleaved"), d_srcid);
            }
        }
        produced += d_ipf;
        d_frame++;
        d_frames++;
    }

    const int64_t next_lo = d_acquire ? acquired_up_to : d_grid + int64_t(d_frame) * d_P - d_W;
    const int64_t keep_from = std::clamp<int64_t>(next_lo, int64_t(R), end);
    if (int64_t(d_tag_scan) < keep_from) { // keep the tags of samples about to be consumed
        std::vector<tag_t> tags;
        get_tags_in_range(tags, 0, std::max<uint64_t>(d_tag_scan, R), uint64_t(keep_from));
        std::sort(tags.begin(), tags.end(), tag_t::offset_compare);
        d_pending.insert(d_pending.end(), tags.begin(), tags.end());
        d_tag_scan = uint64_t(keep_from);
    }
    consume_each(int(keep_from - int64_t(R)));
    return produced;
}

} // namespace thrumapper
} // namespace gr
