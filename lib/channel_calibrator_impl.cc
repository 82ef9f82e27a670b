/* -*- c++ -*- */
/*
 * SPDX-License-Identifier: GPL-3.0-or-later
 */
#include "channel_calibrator_impl.h"
#include <gnuradio/io_signature.h>
#include <algorithm>
#include <cmath>
#include <fstream>

namespace gr {
namespace thrumapper {

namespace {
const pmt::pmt_t k_rx_freq = pmt::mp("rx_freq");

ofdm_sounding::sptr require(ofdm_sounding::sptr s)
{
    if (!s)
        throw std::invalid_argument("channel_calibrator: a sounding description is required");
    return s;
}

int checked_len(const ofdm_sounding::sptr& s, int len)
{
    if (len == 0)
        return 8 * s->frame_len();
    if (len < s->fft_len())
        throw std::invalid_argument("channel_calibrator: calibration_len must be 0 or at least "
                                    "fft_len=" +
                                    std::to_string(s->fft_len()) + ", got " +
                                    std::to_string(len));
    return len;
}

bool file_exists(const std::string& path)
{
    std::ifstream f(path);
    return f.good();
}
} // namespace

channel_calibrator::sptr channel_calibrator::make(ofdm_sounding::sptr sounding,
                                                  const std::string& source,
                                                  int calibration_len,
                                                  int reference_channel,
                                                  bool calibrate_at_start,
                                                  const std::string& coefficients_path,
                                                  int64_t frame_offset)
{
    return gnuradio::make_block_sptr<channel_calibrator_impl>(sounding,
                                                              source,
                                                              calibration_len,
                                                              reference_channel,
                                                              calibrate_at_start,
                                                              coefficients_path,
                                                              frame_offset);
}

channel_calibrator_impl::channel_calibrator_impl(ofdm_sounding::sptr sounding,
                                                 const std::string& source,
                                                 int calibration_len,
                                                 int reference_channel,
                                                 bool calibrate_at_start,
                                                 const std::string& coefficients_path,
                                                 int64_t frame_offset)
    : gr::block("channel_calibrator",
                gr::io_signature::make(require(sounding)->num_rx(),
                                       sounding->num_rx(),
                                       sizeof(gr_complex)),
                gr::io_signature::make(sounding->num_rx(), sounding->num_rx(), sizeof(gr_complex))),
      d_sounding(sounding),
      d_M(sounding->num_rx()),
      d_taps(sounding->fft_len()),
      d_lookahead(sounding->fft_len() / 2),
      d_P(sounding->frame_len()),
      d_len(checked_len(sounding, calibration_len)),
      d_frame_offset(frame_offset),
      d_at_start(calibrate_at_start),
      d_path(coefficients_path),
      d_estimator(sounding, source, reference_channel),
      d_corrector(sounding->num_rx(), sounding->fft_len(), sounding->sample_rate_hz()),
      d_current(calibration_coefficients::identity(sounding->num_rx())),
      d_buffer(d_M, std::vector<gr_complex>(d_len)),
      d_lo_hz(sounding->lo_frequency_hz()),
      d_port(pmt::mp("coefficients"))
{
    if (frame_offset < 0)
        throw std::invalid_argument("channel_calibrator: frame_offset must be >= 0");
    d_current.reference_channel = reference_channel;
    set_history(d_taps);
    set_tag_propagation_policy(TPP_ONE_TO_ONE);
    message_port_register_out(d_port);
    message_port_register_in(pmt::mp("calibrate"));
    set_msg_handler(pmt::mp("calibrate"), [this](const pmt::pmt_t&) { calibrate(); });
}

bool channel_calibrator_impl::start()
{
    if (!d_path.empty() && file_exists(d_path)) {
        auto c = calibration_coefficients::load(d_path);
        if (c.num_channels() != d_M)
            throw std::invalid_argument("channel_calibrator: " + d_path + " holds " +
                                        std::to_string(c.num_channels()) +
                                        " channels, expected " + std::to_string(d_M));
        d_corrector.set_coefficients(c);
        std::lock_guard<std::mutex> lock(d_mutex);
        d_current = c;
        d_logger->info("loaded calibration from {:s}", d_path);
    }
    if (d_at_start) {
        std::lock_guard<std::mutex> lock(d_mutex);
        d_arm_request = true;
        d_arm_why = "start";
    }
    return gr::block::start();
}

void channel_calibrator_impl::calibrate()
{
    std::lock_guard<std::mutex> lock(d_mutex);
    d_arm_request = true;
    d_arm_why = "request";
}

void channel_calibrator_impl::set_coefficients(const calibration_coefficients& c)
{
    c.validate();
    if (c.num_channels() != d_M)
        throw std::invalid_argument("channel_calibrator: coefficients for " +
                                    std::to_string(c.num_channels()) + " channels, expected " +
                                    std::to_string(d_M));
    std::lock_guard<std::mutex> lock(d_mutex);
    d_pending = c;
    d_pending_from = 0;
}

calibration_coefficients channel_calibrator_impl::coefficients() const
{
    std::lock_guard<std::mutex> lock(d_mutex);
    return d_current;
}

void channel_calibrator_impl::save_coefficients(const std::string& path) const
{
    coefficients().save(path);
}

void channel_calibrator_impl::load_coefficients(const std::string& path)
{
    auto c = calibration_coefficients::load(path);
    c.source = "file";
    set_coefficients(c);
}

bool channel_calibrator_impl::calibration_pending() const
{
    std::lock_guard<std::mutex> lock(d_mutex);
    return d_arm_request || d_collecting || d_queued > 0 || d_pending.has_value();
}

void channel_calibrator_impl::arm(uint64_t at, const char* why)
{
    d_collect_start = at;
    d_collected = 0;
    d_collecting = true;
    d_logger->info("calibrating ({:s}) from sample {:d} over {:d} samples", why, at, d_len);
}

pmt::pmt_t channel_calibrator_impl::message(const calibration_coefficients& c,
                                            uint64_t applied_at) const
{
    std::vector<std::complex<double>> dc(c.dc.begin(), c.dc.end());
    pmt::pmt_t msg = pmt::make_dict();
    msg = pmt::dict_add(msg, pmt::mp("dc"), pmt::init_c64vector(dc.size(), dc));
    msg = pmt::dict_add(msg, pmt::mp("gain_db"), pmt::init_f64vector(c.gain_db.size(), c.gain_db));
    msg = pmt::dict_add(
        msg, pmt::mp("phase_rad"), pmt::init_f64vector(c.phase_rad.size(), c.phase_rad));
    msg = pmt::dict_add(msg, pmt::mp("delay_s"), pmt::init_f64vector(c.delay_s.size(), c.delay_s));
    msg = pmt::dict_add(msg, pmt::mp("reference_channel"), pmt::from_long(c.reference_channel));
    msg = pmt::dict_add(msg, pmt::mp("source"), pmt::mp(c.source));
    msg = pmt::dict_add(msg, pmt::mp("center_frequency_hz"), pmt::from_double(c.center_frequency_hz));
    msg = pmt::dict_add(msg, pmt::mp("sample_offset"), pmt::from_uint64(applied_at));
    msg = pmt::dict_add(msg, pmt::mp("calibration_index"), pmt::from_uint64(d_calibrations));
    return msg;
}

void channel_calibrator_impl::finish_collection()
{
    d_collecting = false;
    std::vector<const gr_complex*> ptrs(d_M);
    for (int m = 0; m < d_M; m++)
        ptrs[m] = d_buffer[m].data();
    try {
        auto c = d_estimator.estimate(ptrs.data(), d_M, d_len, d_lo_hz);
        std::lock_guard<std::mutex> lock(d_mutex);
        d_pending = c;
        d_pending_from = d_collect_start + uint64_t(d_len); // not before its own samples
    } catch (const std::exception& e) {
        d_failed++;
        d_logger->warn("calibration from sample {:d} failed ({:d} so far), coefficients kept: {:s}",
                       d_collect_start,
                       uint64_t(d_failed),
                       e.what());
    }
}

void channel_calibrator_impl::forecast(int noutput_items, gr_vector_int& required)
{
    for (auto& r : required) // the history is counted in the items required
        r = noutput_items + d_lookahead + d_taps - 1;
}

int channel_calibrator_impl::general_work(int noutput_items,
                                          gr_vector_int& ninput_items,
                                          gr_vector_const_void_star& input_items,
                                          gr_vector_void_star& output_items)
{
    const uint64_t R = nitems_read(0), Wr = nitems_written(0);
    // ninput_items counts the taps-1 items of history before sample R too
    int n_in = ninput_items[0];
    for (int m = 1; m < d_M; m++)
        n_in = std::min(n_in, ninput_items[m]);
    n_in = std::max(0, n_in - (d_taps - 1));
    const uint64_t end = R + uint64_t(n_in);
    auto sample = [&](int m, uint64_t abs) {
        return static_cast<const gr_complex*>(input_items[m])[d_taps - 1 + int64_t(abs - R)];
    };

    {
        std::lock_guard<std::mutex> lock(d_mutex);
        if (d_arm_request) {
            d_arm_request = false;
            d_arms.emplace_back(R, d_arm_why);
        }
    }
    // retunes: an rx_freq tag with a new value (the chains' phases change)
    if (d_tag_pos < end) {
        std::vector<tag_t> tags;
        get_tags_in_range(tags, 0, std::max(d_tag_pos, R), end, k_rx_freq);
        std::sort(tags.begin(), tags.end(), tag_t::offset_compare);
        for (const auto& t : tags) {
            if (!pmt::is_number(t.value))
                continue;
            const double f = pmt::to_double(t.value);
            if (d_lo_known && f != d_lo_hz) {
                if (d_collecting && t.offset < d_collect_start + uint64_t(d_len)) {
                    d_collecting = false; // its samples straddle the retune: start again
                    d_logger->info("retune at sample {:d}: calibration restarted", t.offset);
                }
                d_arms.emplace_back(t.offset, "retune");
            }
            d_lo_hz = f;
            d_lo_known = true;
        }
        d_tag_pos = end;
    }
    // collect the samples of each requested estimate in turn
    while (true) {
        if (!d_collecting) {
            if (d_arms.empty() || d_arms.front().first >= end)
                break;
            arm(std::max(d_arms.front().first, R), d_arms.front().second);
            d_arms.pop_front();
        }
        const uint64_t from = std::max<uint64_t>(d_collect_start + d_collected, R);
        const uint64_t to = std::min<uint64_t>(d_collect_start + d_len, end);
        for (uint64_t s = from; s < to; s++)
            for (int m = 0; m < d_M; m++)
                d_buffer[m][s - d_collect_start] = sample(m, s);
        if (to > from)
            d_collected = int(to - d_collect_start);
        if (d_collected < d_len)
            break;
        finish_collection();
    }
    d_queued = d_arms.size();

    // outputs lag the inputs by the filter's lookahead; while an estimate is being made,
    // they wait at the first frame boundary after its samples, where it will apply
    int64_t possible = int64_t(end) - d_lookahead - int64_t(Wr);
    if (d_collecting) {
        const uint64_t done = d_collect_start + uint64_t(d_len);
        uint64_t b = uint64_t(d_frame_offset);
        if (done > b)
            b += ((done - b + d_P - 1) / d_P) * uint64_t(d_P);
        possible = std::min<int64_t>(possible, int64_t(b) - int64_t(Wr));
    }
    const int n_out = int(std::max<int64_t>(0, std::min<int64_t>(noutput_items, possible)));
    std::optional<calibration_coefficients> pending;
    uint64_t pending_from = 0;
    {
        std::lock_guard<std::mutex> lock(d_mutex);
        pending = d_pending;
        pending_from = d_pending_from;
    }
    uint64_t o = Wr;
    const uint64_t o_end = Wr + n_out;
    while (o < o_end) {
        uint64_t seg_end = o_end;
        if (pending) {
            // the first frame boundary at or after o (and after the estimate's samples)
            const uint64_t from = std::max(o, pending_from);
            uint64_t b = uint64_t(d_frame_offset);
            if (from > b)
                b += ((from - b + d_P - 1) / d_P) * uint64_t(d_P);
            if (b <= o) {
                d_corrector.set_coefficients(*pending);
                {
                    std::lock_guard<std::mutex> lock(d_mutex);
                    d_current = *pending;
                    if (d_pending && d_pending->to_json() == pending->to_json())
                        d_pending.reset();
                }
                if (!d_path.empty() && pending->source != "file") {
                    try {
                        pending->save(d_path);
                    } catch (const std::exception& e) {
                        d_logger->warn("cannot save the calibration: {:s}", e.what());
                    }
                }
                if (pending->source == "reference" || pending->source == "direct_path")
                    d_calibrations++;
                message_port_pub(d_port, message(*pending, o));
                pending.reset();
            } else {
                seg_end = std::min(o_end, b);
            }
        }
        const int n = int(seg_end - o);
        for (int m = 0; m < d_M; m++) {
            const gr_complex* in = static_cast<const gr_complex*>(input_items[m]) +
                                   (int64_t(o) + d_lookahead - int64_t(R));
            d_corrector.process(m, in, static_cast<gr_complex*>(output_items[m]) + (o - Wr), n);
        }
        o = seg_end;
    }
    const int64_t consume = int64_t(Wr) + n_out + d_lookahead - int64_t(R);
    consume_each(int(std::clamp<int64_t>(consume, 0, n_in)));
    return n_out;
}

} // namespace thrumapper
} // namespace gr
