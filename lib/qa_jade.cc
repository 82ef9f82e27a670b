/* -*- c++ -*- */
/*
 * SPDX-License-Identifier: GPL-3.0-or-later
 */
#include <gnuradio/thrumapper/jade.h>
#include <gnuradio/thrumapper/manifold.h>
#include <boost/test/unit_test.hpp>
#include <cmath>
#include <random>

using namespace gr::thrumapper;
using cd = std::complex<double>;

namespace {
const double deg = M_PI / 180.0;

struct path_spec {
    double aoa_rad, delay_s;
    cd gain;
};

// CSI from the far-field model of the paper (eq. 2-5): Σ_p γ_p a(θ_p) ⊗ g(τ_p), as a
// (M × N) matrix, plus complex white noise of variance noise_var per sample.
Eigen::MatrixXcd model_csi(const radar_description& r,
                           const std::vector<path_spec>& paths,
                           double noise_var,
                           std::mt19937& rng)
{
    const int M = r.num_rx(), N = r.num_subcarriers();
    Eigen::MatrixXcd H = Eigen::MatrixXcd::Zero(M, N);
    for (const auto& p : paths) {
        const Eigen::VectorXcd u = space_time_manifold(r, p.aoa_rad, p.delay_s);
        for (int m = 0; m < M; m++)
            H.row(m) += p.gain * u.segment(m * N, N).transpose();
    }
    if (noise_var > 0) {
        std::normal_distribution<double> n(0.0, std::sqrt(noise_var / 2));
        for (int m = 0; m < M; m++)
            for (int k = 0; k < N; k++)
                H(m, k) += cd(n(rng), n(rng));
    }
    return H;
}

double angle_error(double a, double b)
{
    double d = std::fmod(std::abs(a - b), 2 * M_PI);
    return std::min(d, 2 * M_PI - d);
}

// the path of `found` nearest to (aoa, delay) in normalised distance
const jade_path* nearest(const std::vector<jade_path>& found, double aoa, double delay)
{
    const jade_path* best = nullptr;
    double bd = 1e300;
    for (const auto& p : found) {
        const double d = std::pow(angle_error(p.aoa_rad, aoa) / (5 * deg), 2) +
                         std::pow((p.delay_s - delay) / 1e-9, 2);
        if (d < bd) {
            bd = d;
            best = &p;
        }
    }
    return best;
}
} // namespace

BOOST_AUTO_TEST_CASE(noiseless_peaks_exact_off_grid)
{
    auto r = radar_description::make_uca_pair(8, 0.08, 0.7, 2.44e9, 120e6, 128);
    std::mt19937 rng(1);
    const std::vector<path_spec> truth = { { 263.37 * deg, 7.4321e-9, cd(1.0, 0.3) },
                                           { 101.13 * deg, 19.0877e-9, cd(-0.2, 0.25) } };
    const Eigen::MatrixXcd H = model_csi(*r, truth, 0.0, rng);
    // three grids, none of which holds the true points
    const std::vector<std::pair<int, int>> grids = { { 360, 200 }, { 97, 51 }, { 181, 333 } };
    for (const auto& g : grids) {
        jade j(r, jade::full_circle_grid(g.first), jade::linear_grid(0, 40e-9, g.second), 0, 4);
        const auto found = j.estimate_matrix(H);
        BOOST_REQUIRE_EQUAL(found.size(), 2u);
        BOOST_CHECK_EQUAL(j.model_order(), 2);
        for (const auto& t : truth) {
            const jade_path* p = nearest(found, t.aoa_rad, t.delay_s);
            BOOST_REQUIRE(p);
            BOOST_CHECK_SMALL(angle_error(p->aoa_rad, t.aoa_rad) / deg, 1e-3);
            BOOST_CHECK_SMALL(p->delay_s - t.delay_s, 1e-12);
            BOOST_CHECK_CLOSE(p->power, std::norm(t.gain), 1e-3);
        }
    }
}

BOOST_AUTO_TEST_CASE(single_path_rms_within_3x_crb)
{
    const int M = 8, N = 128;
    const double radius = 0.08, fc = 2.44e9, bw = 120e6;
    auto r = radar_description::make_uca_pair(M, radius, 0.7, fc, bw, N);
    const double snr = 10.0; // 10 dB per sample
    const double df = r->subcarrier_spacing_hz();
    const double kr = 2 * M_PI * fc / speed_of_light_m_s * radius;
    const double crb_tau = 1.0 / (8 * M_PI * M_PI * snr * M * df * df * N * (double(N) * N - 1) / 12);
    const double crb_theta = 1.0 / (snr * N * M * kr * kr);
    const path_spec truth{ 247.3 * deg, 11.2e-9, std::polar(1.0, 0.4) };
    jade j(r, jade::full_circle_grid(360), jade::linear_grid(0, 40e-9, 200), 0, 1);
    std::mt19937 rng(20261122);
    double se_tau = 0, se_theta = 0;
    const int trials = 200;
    for (int t = 0; t < trials; t++) {
        const Eigen::MatrixXcd H = model_csi(*r, { truth }, 1.0 / snr, rng);
        const auto found = j.estimate_matrix(H);
        BOOST_REQUIRE_EQUAL(found.size(), 1u);
        se_tau += std::pow(found[0].delay_s - truth.delay_s, 2);
        se_theta += std::pow(angle_error(found[0].aoa_rad, truth.aoa_rad), 2);
    }
    const double rms_tau = std::sqrt(se_tau / trials), rms_theta = std::sqrt(se_theta / trials);
    BOOST_TEST_MESSAGE("delay RMS " << rms_tau * 1e12 << " ps (CRB " << std::sqrt(crb_tau) * 1e12
                                    << " ps), angle RMS " << rms_theta / deg << " deg (CRB "
                                    << std::sqrt(crb_theta) / deg << " deg)");
    BOOST_CHECK_LE(rms_tau, 3 * std::sqrt(crb_tau));
    BOOST_CHECK_LE(rms_theta, 3 * std::sqrt(crb_theta));
    // and it is an estimator, not a coincidence: the errors are not below the bound
    BOOST_CHECK_GE(rms_tau, 0.5 * std::sqrt(crb_tau));
}

BOOST_AUTO_TEST_CASE(two_coherent_paths_resolved)
{
    // 15° and 3 ns apart: both below the Fourier resolution of the array (≈ 40°) and of the
    // band (1/B = 8.3 ns), and fully coherent (one frame, fixed phases).
    auto r = radar_description::make_uca_pair(8, 0.08, 0.7, 2.44e9, 120e6, 128);
    std::mt19937 rng(7);
    const std::vector<path_spec> truth = { { 270 * deg, 8.0e-9, cd(1, 0) },
                                           { 285 * deg, 11.0e-9, cd(0, 0.8) } };
    const Eigen::MatrixXcd H = model_csi(*r, truth, 0.01, rng); // 20 dB per sample
    jade j(r, jade::full_circle_grid(360), jade::linear_grid(0, 40e-9, 200), 0, 4);
    const auto found = j.estimate_matrix(H);
    BOOST_REQUIRE_GE(found.size(), 2u);
    for (const auto& t : truth) {
        const jade_path* p = nearest(found, t.aoa_rad, t.delay_s);
        BOOST_REQUIRE(p);
        BOOST_CHECK_SMALL(angle_error(p->aoa_rad, t.aoa_rad) / deg, 1.0);
        BOOST_CHECK_SMALL((p->delay_s - t.delay_s) * 1e9, 0.2);
    }
}

BOOST_AUTO_TEST_CASE(model_order_one_to_five_paths)
{
    auto r = radar_description::make_uca_pair(8, 0.08, 0.7, 2.44e9, 120e6, 128);
    std::mt19937 rng(99);
    std::uniform_real_distribution<double> ph(0, 2 * M_PI);
    const double aoas[5] = { 30, 100, 170, 240, 310 };
    const double delays[5] = { 5e-9, 11e-9, 17e-9, 23e-9, 29e-9 };
    jade j(r, jade::full_circle_grid(360), jade::linear_grid(0, 40e-9, 200), 0, 8);
    for (int P = 1; P <= 5; P++) {
        for (int trial = 0; trial < 10; trial++) {
            std::vector<path_spec> truth;
            for (int p = 0; p < P; p++)
                truth.push_back({ aoas[p] * deg, delays[p], std::polar(1.0, ph(rng)) });
            const Eigen::MatrixXcd H = model_csi(*r, truth, 0.01, rng); // 20 dB per path
            const auto found = j.estimate_matrix(H);
            BOOST_CHECK_EQUAL(j.model_order(), P);
            BOOST_CHECK_EQUAL(found.size(), size_t(P));
        }
    }
    // noise alone: no path (the false-alarm side of the order rule)
    for (int trial = 0; trial < 200; trial++) {
        const Eigen::MatrixXcd H = model_csi(*r, {}, 1.0, rng);
        const auto found = j.estimate_matrix(H);
        BOOST_CHECK_EQUAL(found.size(), 0u);
    }
}

BOOST_AUTO_TEST_CASE(frames_of_one_pose_stack)
{
    // Four noisy frames of one pose: stacking their snapshots beats any single frame.
    auto r = radar_description::make_uca_pair(8, 0.08, 0.7, 2.44e9, 120e6, 64);
    std::mt19937 rng(5);
    const path_spec truth{ 200 * deg, 9e-9, cd(1, 0) };
    jade j(r, jade::full_circle_grid(180), jade::linear_grid(0, 40e-9, 100), 0, 1);
    double se1 = 0, se4 = 0;
    for (int t = 0; t < 60; t++) {
        Eigen::MatrixXcd frames(4 * 8, 64);
        for (int f = 0; f < 4; f++)
            frames.middleRows(f * 8, 8) = model_csi(*r, { truth }, 1.0, rng); // 0 dB
        se1 += std::pow(j.estimate_matrix(frames.topRows(8))[0].delay_s - truth.delay_s, 2);
        se4 += std::pow(j.estimate_matrix(frames)[0].delay_s - truth.delay_s, 2);
    }
    // four times the snapshots: the variance drops by about four; demand at least two
    BOOST_CHECK_LT(se4, se1 / 2);
}

BOOST_AUTO_TEST_CASE(smoothing_is_hankel)
{
    Eigen::MatrixXcd H(2, 6);
    for (int m = 0; m < 2; m++)
        for (int n = 0; n < 6; n++)
            H(m, n) = cd(10 * m + n, -n);
    const Eigen::MatrixXcd Y = jade::smooth(H, 2, 4);
    BOOST_REQUIRE_EQUAL(Y.rows(), 8);
    BOOST_REQUIRE_EQUAL(Y.cols(), 3);
    for (int m = 0; m < 2; m++)
        for (int l = 0; l < 4; l++)
            for (int i = 0; i < 3; i++)
                BOOST_CHECK(Y(m * 4 + l, i) == H(m, i + l));
}

BOOST_AUTO_TEST_CASE(signal_subspace_orthonormal_and_contains_paths)
{
    auto r = radar_description::make_uca_pair(8, 0.08, 0.7, 2.44e9, 120e6, 128);
    std::mt19937 rng(3);
    const std::vector<path_spec> truth = { { 10 * deg, 4e-9, cd(1, 0) }, { 200 * deg, 14e-9, cd(0.5, 0.5) } };
    jade j(r, jade::full_circle_grid(90), jade::linear_grid(0, 40e-9, 50), 0, 4);
    j.estimate_matrix(model_csi(*r, truth, 0, rng));
    const Eigen::MatrixXcd& E = j.signal_subspace();
    BOOST_CHECK_SMALL((E.adjoint() * E - Eigen::MatrixXcd::Identity(E.cols(), E.cols())).norm(), 1e-9);
    for (const auto& t : truth)
        BOOST_CHECK_CLOSE(j.subspace_fit(t.aoa_rad, t.delay_s), 1.0, 1e-6);
}

BOOST_AUTO_TEST_CASE(bad_frames_throw_with_clear_errors)
{
    auto r = radar_description::make_uca_pair(8, 0.08, 0.7, 2.44e9, 120e6, 64);
    jade j(r, jade::full_circle_grid(90), jade::linear_grid(0, 40e-9, 50), 0, 4);
    std::mt19937 rng(11);
    Eigen::MatrixXcd H = model_csi(*r, { { 1.0, 5e-9, cd(1, 0) } }, 0.01, rng);
    Eigen::MatrixXcd bad = H;
    bad(3, 7) = cd(NAN, 0);
    BOOST_CHECK_THROW(j.estimate_matrix(bad), std::invalid_argument);
    bad = H;
    bad(0, 0) = cd(INFINITY, 0);
    BOOST_CHECK_THROW(j.estimate_matrix(bad), std::invalid_argument);
    BOOST_CHECK_THROW(j.estimate_matrix(Eigen::MatrixXcd::Zero(8, 64)), std::invalid_argument);
    BOOST_CHECK_THROW(j.estimate_matrix(H.leftCols(63)), std::invalid_argument);
    BOOST_CHECK_THROW(j.estimate_matrix(H.topRows(7)), std::invalid_argument);
    BOOST_CHECK_THROW(j.set_smoothing_window(64), std::invalid_argument);
    BOOST_CHECK_THROW(j.set_max_paths(0), std::invalid_argument);
    BOOST_CHECK_THROW(j.set_delay_grid({}), std::invalid_argument);
    // the estimator still works after the errors
    BOOST_CHECK_EQUAL(j.estimate_matrix(H).size(), 1u);
}
