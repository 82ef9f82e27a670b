/* -*- c++ -*- */
/*
 * SPDX-License-Identifier: GPL-3.0-or-later
 */
#include <gnuradio/thrumapper/manifold.h>
#include <cmath>
#include <complex>
#include <stdexcept>

namespace gr {
namespace thrumapper {

using cd = std::complex<double>;

Eigen::VectorXcd steering_far_field(const radar_description::positions_t& elements_m,
                                    double aoa_rad,
                                    double freq_hz)
{
    const Eigen::RowVector2d centre = elements_m.colwise().mean();
    const double k = 2.0 * M_PI * freq_hz / speed_of_light_m_s;
    const double ux = std::cos(aoa_rad), uy = std::sin(aoa_rad);
    Eigen::VectorXcd a(elements_m.rows());
    for (int m = 0; m < elements_m.rows(); m++) {
        const double proj = (elements_m(m, 0) - centre(0)) * ux + (elements_m(m, 1) - centre(1)) * uy;
        a(m) = std::polar(1.0, k * proj);
    }
    return a;
}

Eigen::VectorXcd steering_near_field(const radar_description::positions_t& elements_m,
                                     const Eigen::Vector2d& source_m,
                                     double freq_hz)
{
    const Eigen::Vector2d centre = elements_m.colwise().mean().transpose();
    const double d0 = (centre - source_m).norm();
    if (!(d0 > 0))
        throw std::invalid_argument("steering_near_field: the source is at the array centre");
    const double k = 2.0 * M_PI * freq_hz / speed_of_light_m_s;
    Eigen::VectorXcd a(elements_m.rows());
    for (int m = 0; m < elements_m.rows(); m++) {
        const double dm = (elements_m.row(m).transpose() - source_m).norm();
        if (!(dm > 0))
            throw std::invalid_argument("steering_near_field: the source is on an element");
        a(m) = (d0 / dm) * std::polar(1.0, -k * (dm - d0));
    }
    return a;
}

Eigen::VectorXcd delay_manifold(const std::vector<double>& subcarrier_offsets_hz, double delay_s)
{
    Eigen::VectorXcd g(subcarrier_offsets_hz.size());
    for (size_t n = 0; n < subcarrier_offsets_hz.size(); n++)
        g(n) = std::polar(1.0, -2.0 * M_PI * subcarrier_offsets_hz[n] * delay_s);
    return g;
}

Eigen::VectorXcd space_time_manifold(const radar_description& radar, double aoa_rad, double delay_s)
{
    const Eigen::VectorXcd a = steering_far_field(radar.rx_elements_m(), aoa_rad, radar.carrier_hz());
    const Eigen::VectorXcd g = delay_manifold(radar.subcarrier_offsets_hz(), delay_s);
    const int M = a.size(), N = g.size();
    Eigen::VectorXcd u(M * N);
    for (int m = 0; m < M; m++)
        u.segment(m * N, N) = a(m) * g;
    return u;
}

Eigen::VectorXcd direct_path_response(const radar_description& radar,
                                      const std::vector<gr_complex>& tx_weights,
                                      double system_delay_s)
{
    const int M = radar.num_rx(), N = radar.num_subcarriers(), K = radar.num_tx();
    const std::vector<gr_complex>& w = tx_weights.empty() ? radar.tx_weights() : tx_weights;
    if (static_cast<int>(w.size()) != K)
        throw std::invalid_argument("direct_path_response: expected " + std::to_string(K) +
                                    " TX weights, got " + std::to_string(w.size()));
    const auto& tx = radar.tx_elements_m();
    const auto& rx = radar.rx_elements_m();
    const auto& df = radar.subcarrier_offsets_hz();
    Eigen::VectorXcd h = Eigen::VectorXcd::Zero(M * N);
    for (int m = 0; m < M; m++)
        for (int k = 0; k < K; k++) {
            const double d = (tx.row(k) - rx.row(m)).norm();
            const double tau = d / speed_of_light_m_s + system_delay_s;
            const cd wk(w[k].real(), w[k].imag());
            for (int n = 0; n < N; n++) {
                // free space between isotropic elements: amplitude λ/(4πd), delay d/c
                const double f = radar.carrier_hz() + df[n];
                h(m * N + n) += wk * std::polar(speed_of_light_m_s / (4.0 * M_PI * f * d),
                                                -2.0 * M_PI * f * tau);
            }
        }
    return h;
}

} // namespace thrumapper
} // namespace gr
