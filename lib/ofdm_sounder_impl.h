/* -*- c++ -*- */
/*
 * SPDX-License-Identifier: GPL-3.0-or-later
 */
#ifndef INCLUDED_THRUMAPPER_OFDM_SOUNDER_IMPL_H
#define INCLUDED_THRUMAPPER_OFDM_SOUNDER_IMPL_H

#include <gnuradio/thrumapper/ofdm_sounder.h>
#include <atomic>
#include <mutex>

namespace gr {
namespace thrumapper {

class ofdm_sounder_impl : public ofdm_sounder
{
private:
    ofdm_sounding::sptr d_sounding;
    const int d_K, d_P;
    const double d_start_time_s;
    mutable std::mutex d_mutex; // guards d_pending
    std::vector<gr_complex> d_pending;
    bool d_changed = true;
    std::vector<gr_complex> d_active;
    std::vector<std::vector<gr_complex>> d_frame; // the current frame of every element
    int d_pos = 0;                                 // next sample of the current frame
    uint64_t d_frame_index = 0;
    std::atomic<uint64_t> d_frames{ 0 };
    std::atomic<uint64_t> d_rejected{ 0 };
    const pmt::pmt_t d_srcid;

    std::vector<gr_complex> check_weights(const std::vector<gr_complex>& w) const;
    void handle_weights(const pmt::pmt_t& msg);
    void start_frame(uint64_t abs_offset);

public:
    ofdm_sounder_impl(ofdm_sounding::sptr sounding,
                      const std::vector<gr_complex>& weights,
                      double start_time_s);

    int work(int noutput_items,
             gr_vector_const_void_star& input_items,
             gr_vector_void_star& output_items) override;

    void set_weights(const std::vector<gr_complex>& weights) override;
    std::vector<gr_complex> weights() const override;
    uint64_t num_frames() const override { return d_frames; }
    uint64_t num_rejected_weights() const override { return d_rejected; }
};

} // namespace thrumapper
} // namespace gr

#endif
