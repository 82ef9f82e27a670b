/* -*- c++ -*- */
/*
 * SPDX-License-Identifier: GPL-3.0-or-later
 */
#ifndef INCLUDED_THRUMAPPER_JADE_ESTIMATOR_IMPL_H
#define INCLUDED_THRUMAPPER_JADE_ESTIMATOR_IMPL_H

#include <gnuradio/thrumapper/jade.h>
#include <gnuradio/thrumapper/jade_estimator.h>
#include <atomic>
#include <mutex>

namespace gr {
namespace thrumapper {

class jade_estimator_impl : public jade_estimator
{
private:
    radar_description::sptr d_radar;
    const int d_M, d_N, d_num_angles, d_num_delays;
    mutable std::mutex d_mutex; // guards d_jade: setters come from other threads
    jade d_jade;
    std::atomic<uint64_t> d_skipped{ 0 };
    std::atomic<uint64_t> d_estimated{ 0 };
    uint64_t d_frame_counter = 0;
    std::atomic<bool> d_attach_csi{ false };
    const pmt::pmt_t d_port;

    static std::vector<double> angle_grid(int count, double min_deg, double max_deg);

public:
    jade_estimator_impl(radar_description::sptr radar,
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
                        bool attach_csi);

    void forecast(int noutput_items, gr_vector_int& ninput_items_required) override;
    int general_work(int noutput_items,
                     gr_vector_int& ninput_items,
                     gr_vector_const_void_star& input_items,
                     gr_vector_void_star& output_items) override;

    void set_angle_span(double angle_min_deg, double angle_max_deg) override;
    void set_delay_span(double delay_min_s, double delay_max_s) override;
    void set_max_paths(int max_paths) override;
    void set_smoothing_window(int subcarriers) override;
    void set_system_delay(double system_delay_s) override;
    void set_model_order(int order) override;
    void set_stages(int stages) override;
    int stages() const override;
    void set_attach_csi(bool attach_csi) override { d_attach_csi = attach_csi; }
    bool attach_csi() const override { return d_attach_csi; }

    int num_angles() const override { return d_num_angles; }
    int num_delays() const override { return d_num_delays; }
    int max_paths() const override;
    int smoothing_window() const override;
    double system_delay() const override;
    uint64_t num_skipped() const override { return d_skipped; }
    uint64_t num_estimated() const override { return d_estimated; }
};

} // namespace thrumapper
} // namespace gr

#endif
