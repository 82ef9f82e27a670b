/* -*- c++ -*- */
/*
 * SPDX-License-Identifier: GPL-3.0-or-later
 */
#ifndef INCLUDED_THRUMAPPER_CHANNEL_CALIBRATOR_IMPL_H
#define INCLUDED_THRUMAPPER_CHANNEL_CALIBRATOR_IMPL_H

#include <gnuradio/thrumapper/channel_calibrator.h>
#include <atomic>
#include <deque>
#include <mutex>
#include <optional>

namespace gr {
namespace thrumapper {

class channel_calibrator_impl : public channel_calibrator
{
private:
    ofdm_sounding::sptr d_sounding;
    const int d_M, d_taps, d_lookahead, d_P, d_len;
    const int64_t d_frame_offset;
    const bool d_at_start;
    const std::string d_path;
    channel_calibration d_estimator; // work thread only
    channel_corrector d_corrector;   // work thread only
    mutable std::mutex d_mutex;      // guards the members below it
    calibration_coefficients d_current;
    std::optional<calibration_coefficients> d_pending;
    uint64_t d_pending_from = 0; // the pending coefficients apply at a boundary >= this
    bool d_arm_request = false;
    const char* d_arm_why = "request";
    std::atomic<bool> d_collecting{ false };
    std::atomic<size_t> d_queued{ 0 }; // d_arms.size(), for other threads
    // work thread state
    std::deque<std::pair<uint64_t, const char*>> d_arms; // where estimates are to start
    uint64_t d_collect_start = 0;
    int d_collected = 0;
    std::vector<std::vector<gr_complex>> d_buffer;
    uint64_t d_tag_pos = 0;
    double d_lo_hz;
    bool d_lo_known = false;
    std::atomic<uint64_t> d_calibrations{ 0 }, d_failed{ 0 };
    const pmt::pmt_t d_port;

    void arm(uint64_t at, const char* why);
    void finish_collection();
    pmt::pmt_t message(const calibration_coefficients& c, uint64_t applied_at) const;

public:
    channel_calibrator_impl(ofdm_sounding::sptr sounding,
                            const std::string& source,
                            int calibration_len,
                            int reference_channel,
                            bool calibrate_at_start,
                            const std::string& coefficients_path,
                            int64_t frame_offset);

    bool start() override;
    void forecast(int noutput_items, gr_vector_int& ninput_items_required) override;
    int general_work(int noutput_items,
                     gr_vector_int& ninput_items,
                     gr_vector_const_void_star& input_items,
                     gr_vector_void_star& output_items) override;

    void calibrate() override;
    void set_coefficients(const calibration_coefficients& c) override;
    calibration_coefficients coefficients() const override;
    void save_coefficients(const std::string& path) const override;
    void load_coefficients(const std::string& path) override;
    uint64_t num_calibrations() const override { return d_calibrations; }
    uint64_t num_failed_calibrations() const override { return d_failed; }
    bool calibration_pending() const override;
    int calibration_len() const override { return d_len; }
};

} // namespace thrumapper
} // namespace gr

#endif
