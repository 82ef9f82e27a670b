/* -*- c++ -*- */
/*
 * SPDX-License-Identifier: GPL-3.0-or-later
 */
#ifndef INCLUDED_THRUMAPPER_OFDM_CHANNEL_ESTIMATOR_IMPL_H
#define INCLUDED_THRUMAPPER_OFDM_CHANNEL_ESTIMATOR_IMPL_H

#include <gnuradio/thrumapper/ofdm_channel_estimator.h>
#include <atomic>
#include <deque>
#include <memory>

namespace gr {
namespace thrumapper {

class ofdm_channel_estimator_impl : public ofdm_channel_estimator
{
private:
    ofdm_sounding::sptr d_sounding;
    const int d_M, d_N, d_P, d_ipf, d_W, d_backoff;
    ofdm_demodulator d_demod;
    std::unique_ptr<ofdm_demodulator> d_acquire; // while the frame timing is unknown
    std::atomic<double> d_threshold;
    const int d_span;
    int64_t d_grid;       // stream offset of frame 0's grid position (moves at overflows)
    uint64_t d_frame = 0; // next frame index
    // time base: the latest rx_time tag (or sample 0 at time 0)
    uint64_t d_anchor_offset = 0;
    uint64_t d_anchor_secs = 0;
    double d_anchor_frac = 0.0;
    bool d_have_time = false;
    int64_t d_last_discontinuity = INT64_MIN;
    std::deque<tag_t> d_pending; // input-0 tags collected but not yet applied
    uint64_t d_tag_scan = 0;     // tags before this offset have been collected
    pmt::pmt_t d_pose = pmt::PMT_NIL, d_rx_freq = pmt::PMT_NIL, d_frame_type = pmt::PMT_NIL;
    std::vector<std::vector<gr_complex>> d_scratch;
    std::vector<const gr_complex*> d_ptrs;
    std::atomic<uint64_t> d_frames{ 0 }, d_missing{ 0 }, d_disc_skips{ 0 }, d_discontinuities{ 0 };
    const pmt::pmt_t d_srcid;

    void apply_time_tag(const tag_t& tag);
    pmt::pmt_t time_of(int64_t offset) const;
    void skip(std::atomic<uint64_t>& counter, const char* reason, double metric);

public:
    ofdm_channel_estimator_impl(ofdm_sounding::sptr sounding,
                                int64_t frame_offset,
                                int search_window,
                                int timing_backoff,
                                double detection_threshold);

    void forecast(int noutput_items, gr_vector_int& ninput_items_required) override;
    int general_work(int noutput_items,
                     gr_vector_int& ninput_items,
                     gr_vector_const_void_star& input_items,
                     gr_vector_void_star& output_items) override;

    void set_detection_threshold(double threshold) override;
    double detection_threshold() const override { return d_threshold; }
    int search_window() const override { return d_W; }
    int timing_backoff() const override { return d_backoff; }
    uint64_t num_frames() const override { return d_frames; }
    uint64_t num_missing_preamble() const override { return d_missing; }
    uint64_t num_discontinuity_skips() const override { return d_disc_skips; }
    uint64_t num_discontinuities() const override { return d_discontinuities; }
};

} // namespace thrumapper
} // namespace gr

#endif
