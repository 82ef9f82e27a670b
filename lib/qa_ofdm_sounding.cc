/* -*- c++ -*- */
/*
 * SPDX-License-Identifier: GPL-3.0-or-later
 */
#include <gnuradio/thrumapper/channel_calibration.h>
#include <gnuradio/thrumapper/ofdm_sounding.h>
#include <boost/test/unit_test.hpp>
#include <cmath>
#include <cstdio>
#include <random>

using namespace gr::thrumapper;

namespace {
ofdm_sounding::sptr paper_sounding(sounding_mode mode = sounding_mode::weighted)
{
    return ofdm_sounding::make(radar_description::make_uca_pair(), 120e6, 256, 64, 4, 128, 64, mode);
}

// M channels: channel m = gain_m · (frames delayed by delay samples), frames back to back
std::vector<std::vector<gr_complex>> receive(const ofdm_sounding& s,
                                             int frames,
                                             int delay,
                                             const std::vector<gr_complex>& gain)
{
    const int P = s.frame_len();
    std::vector<gr_complex> tx(size_t(frames) * P, gr_complex(0, 0));
    std::vector<gr_complex> one(P);
    for (int k = 0; k < s.num_tx(); k++) {
        s.frame_samples(k, {}, one.data());
        for (int f = 0; f < frames; f++)
            for (int t = 0; t < P; t++)
                tx[size_t(f) * P + t] += one[t];
    }
    std::vector<std::vector<gr_complex>> rx(gain.size(), std::vector<gr_complex>(tx.size()));
    for (size_t m = 0; m < gain.size(); m++)
        for (size_t t = delay; t < tx.size(); t++)
            rx[m][t] = gain[m] * tx[t - delay];
    return rx;
}
} // namespace

BOOST_AUTO_TEST_CASE(t_bins_of_the_paper_radar_are_the_odd_bins)
{
    auto s = paper_sounding();
    BOOST_REQUIRE_EQUAL(s->num_subcarriers(), 128);
    for (int n = 0; n < 128; n++)
        BOOST_CHECK_EQUAL(s->subcarrier_signed_bins()[n], 2 * n - 127);
    BOOST_CHECK_EQUAL(s->frame_len(), 128 + (2 * 64 + 5 * 256) + 64);
    BOOST_CHECK_CLOSE(s->bin_spacing_hz(), 468750.0, 1e-9);
}

BOOST_AUTO_TEST_CASE(t_bad_waveforms_are_refused)
{
    auto radar = radar_description::make_uca_pair();
    // 122.88 MS/s, FFT 128: 960 kHz bins do not divide the 937.5 kHz subcarrier grid
    BOOST_CHECK_THROW(ofdm_sounding::make(radar, 122.88e6, 128), std::invalid_argument);
    // 120 MS/s, FFT 128: the offsets are half bins
    BOOST_CHECK_THROW(ofdm_sounding::make(radar, 120e6, 128), std::invalid_argument);
    // ... unless the LO moves by half a subcarrier; then one subcarrier sits on DC
    BOOST_CHECK_THROW(ofdm_sounding::make(radar, 120e6, 128, 32, 4, 128, 64,
                                          sounding_mode::weighted, 468750.0),
                      std::invalid_argument);
    BOOST_CHECK_THROW(ofdm_sounding::make(radar, 120e6, 256, 300), std::invalid_argument);
    BOOST_CHECK_THROW(ofdm_sounding::make(nullptr), std::invalid_argument);
}

BOOST_AUTO_TEST_CASE(t_training_is_periodic_with_constant_envelope)
{
    auto s = paper_sounding();
    const auto& f = s->unweighted_frame(0);
    const int F = s->fft_len();
    const float level = std::sqrt(128.0f / 256.0f);
    for (int u = s->slot_start(0) + F; u < s->slot_start(0) + s->slot_len(); u++)
        BOOST_CHECK_SMALL(std::abs(f[u] - f[u - F]), 1e-6f);
    for (int u = s->slot_start(0); u < s->slot_start(0) + s->slot_len(); u++)
        BOOST_CHECK_CLOSE(std::abs(f[u]), level, 0.01);
    // the preamble: a chirp less its small DC (the frame has no DC): PAPR below 1 dB
    double peak = 0, power = 0;
    for (int u = 0; u < s->preamble_len(); u++) {
        peak = std::max(peak, double(std::norm(f[u])));
        power += std::norm(f[u]) / s->preamble_len();
    }
    BOOST_CHECK_LT(10 * std::log10(peak / power), 1.0);
    std::complex<double> sum = 0;
    for (const auto& v : f)
        sum += std::complex<double>(v);
    BOOST_CHECK_SMALL(std::abs(sum), 1e-4);
    for (int u = s->burst_len(); u < s->frame_len(); u++)
        BOOST_CHECK_EQUAL(f[u], gr_complex(0, 0));
}

BOOST_AUTO_TEST_CASE(t_timing_and_least_squares_csi_are_exact_for_a_delayed_channel)
{
    auto s = paper_sounding();
    const int M = s->num_rx(), N = s->num_subcarriers(), F = s->fft_len(), delay = 5;
    std::vector<gr_complex> gain;
    for (int m = 0; m < M; m++)
        gain.push_back(std::polar(0.5f + 0.1f * m, 0.7f * m));
    auto rx = receive(*s, 3, delay, gain);
    ofdm_demodulator demod(s, 32, 16, 0.3);
    // frame 1: the search origin is 32 samples before its grid position
    std::vector<const gr_complex*> p(M);
    for (int m = 0; m < M; m++)
        p[m] = rx[m].data() + s->frame_len() - 32;
    auto d = demod.detect(p.data(), M);
    BOOST_CHECK(d.found);
    BOOST_CHECK_EQUAL(d.offset, delay);
    BOOST_CHECK_GT(d.metric, 0.99);
    std::vector<gr_complex> csi(size_t(M) * N);
    demod.estimate(p.data(), M, d.offset, 0.0, csi.data());
    for (int m = 0; m < M; m++) {
        for (int n = 0; n < N; n++) {
            // the sum over 8 elements of weight 1, delayed by `delay` samples
            const double a = -2.0 * M_PI * s->subcarrier_signed_bins()[n] * delay / F;
            const gr_complex expected = 8.0f * gain[m] * gr_complex(std::cos(a), std::sin(a));
            BOOST_CHECK_SMALL(std::abs(csi[m * N + n] - expected), 1e-4f);
        }
    }
}

BOOST_AUTO_TEST_CASE(t_noise_alone_is_not_a_preamble)
{
    auto s = paper_sounding();
    const int M = s->num_rx();
    ofdm_demodulator demod(s, 64, 16, 0.3);
    std::mt19937 rng(3);
    std::normal_distribution<float> g;
    std::vector<std::vector<gr_complex>> noise(M, std::vector<gr_complex>(demod.span()));
    std::vector<const gr_complex*> p(M);
    for (int m = 0; m < M; m++) {
        for (auto& v : noise[m])
            v = gr_complex(g(rng), g(rng));
        p[m] = noise[m].data();
    }
    auto d = demod.detect(p.data(), M);
    BOOST_CHECK(!d.found);
    BOOST_CHECK_LT(d.metric, 0.1);
}

BOOST_AUTO_TEST_CASE(t_calibration_recovers_gain_phase_delay_and_the_corrector_undoes_them)
{
    auto s = paper_sounding();
    const int M = s->num_rx(), F = s->fft_len(), P = s->frame_len(), frames = 8;
    calibration_coefficients truth = calibration_coefficients::identity(M);
    for (int m = 1; m < M; m++) {
        truth.gain_db[m] = 0.7 * m - 2.0;
        truth.phase_rad[m] = std::remainder(1.3 * m, 2 * M_PI);
        truth.delay_s[m] = (m % 3 - 1) * 0.37e-9;
        truth.dc[m] = gr_complex(0.01f * m, -0.005f);
    }
    // the reference: the sounding of element 0, periodic over `frames` frames; every chain
    // applies its response on the FFT bins of the whole record (exact, circular)
    const int L = frames * P;
    gr::fft::fft_complex_fwd fwd(L, 1);
    gr::fft::fft_complex_rev rev(L, 1);
    for (int f = 0; f < frames; f++)
        s->frame_samples(0, {}, fwd.get_inbuf() + size_t(f) * P);
    fwd.execute();
    std::vector<gr_complex> spectrum(fwd.get_outbuf(), fwd.get_outbuf() + L);
    std::vector<std::vector<gr_complex>> rx(M, std::vector<gr_complex>(L));
    for (int m = 0; m < M; m++) {
        for (int k = 0; k < L; k++) {
            const int kk = k >= L / 2 ? k - L : k;
            rev.get_inbuf()[k] = spectrum[k] * truth.chain_response(m, kk * 120e6 / L) / float(L);
        }
        rev.execute();
        for (int t = 0; t < L; t++)
            rx[m][t] = rev.get_outbuf()[t] + truth.dc[m];
    }
    std::vector<const gr_complex*> p(M);
    for (int m = 0; m < M; m++)
        p[m] = rx[m].data();
    channel_calibration cal(s, "reference", 0);
    auto c = cal.estimate(p.data(), M, L);
    for (int m = 0; m < M; m++) {
        BOOST_CHECK_SMALL(c.gain_db[m] - truth.gain_db[m], 0.01);
        BOOST_CHECK_SMALL(std::remainder(c.phase_rad[m] - truth.phase_rad[m], 2 * M_PI),
                          0.2 * M_PI / 180);
        BOOST_CHECK_SMALL(c.delay_s[m] - truth.delay_s[m], 5e-12);
        BOOST_CHECK_SMALL(std::abs(c.dc[m] - truth.dc[m]), 2e-3f);
    }
    // the corrector makes every channel channel 0 again (on the sounding's bins)
    channel_corrector corr(M, F, 120e6);
    corr.set_coefficients(c);
    const int n = L - (F - 1), shift = F - 1 - corr.lookahead();
    std::vector<gr_complex> out(n);
    double err = 0, ref = 0;
    std::vector<gr_complex> out0(n);
    corr.process(0, rx[0].data(), out0.data(), n);
    for (int m = 1; m < M; m++) {
        corr.process(m, rx[m].data(), out.data(), n);
        for (int t = P; t < n - P; t++) {
            err += std::norm(out[t] - out0[t]);
            ref += std::norm(rx[0][t + shift]);
        }
    }
    BOOST_CHECK_LT(10 * std::log10(err / ref), -40.0);
}

BOOST_AUTO_TEST_CASE(t_calibration_json_round_trip_and_errors)
{
    calibration_coefficients c = calibration_coefficients::identity(3);
    c.gain_db = { 0.0, 1.25, -0.5 };
    c.phase_rad = { 0.0, 0.1, -3.0 };
    c.delay_s = { 0.0, 1e-10, -2.5e-11 };
    c.dc = { gr_complex(0, 0), gr_complex(1e-3f, 2e-3f), gr_complex(-1e-4f, 0) };
    c.source = "reference";
    c.center_frequency_hz = 2.44e9;
    c.sample_rate_hz = 120e6;
    const std::string path = "qa_calibration_round_trip.json";
    c.save(path);
    auto d = calibration_coefficients::load(path);
    std::remove(path.c_str());
    BOOST_CHECK_EQUAL(d.num_channels(), 3);
    for (int m = 0; m < 3; m++) {
        BOOST_CHECK_EQUAL(d.gain_db[m], c.gain_db[m]);
        BOOST_CHECK_EQUAL(d.phase_rad[m], c.phase_rad[m]);
        BOOST_CHECK_EQUAL(d.delay_s[m], c.delay_s[m]);
        BOOST_CHECK_EQUAL(d.dc[m], c.dc[m]);
    }
    BOOST_CHECK_EQUAL(d.source, "reference");
    BOOST_CHECK_EQUAL(d.center_frequency_hz, 2.44e9);
    BOOST_CHECK_THROW(calibration_coefficients::from_json("{\"channels\": []}"),
                      std::invalid_argument);
    BOOST_CHECK_THROW(calibration_coefficients::from_json("not json"), std::invalid_argument);
}
