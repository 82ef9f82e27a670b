/* -*- c++ -*- */
/*
 * SPDX-License-Identifier: GPL-3.0-or-later
 */
#include <gnuradio/thrumapper/radar_description.h>
#include <cmath>
#include <sstream>
#include <stdexcept>

namespace gr {
namespace thrumapper {

namespace {
void check_positions(const radar_description::positions_t& p, const char* name)
{
    if (p.rows() < 1)
        throw std::invalid_argument(std::string(name) + ": at least one element is needed");
    if (!p.allFinite())
        throw std::invalid_argument(std::string(name) + ": positions must be finite");
}
} // namespace

radar_description::radar_description(const positions_t& tx_elements_m,
                                     const positions_t& rx_elements_m,
                                     double carrier_hz,
                                     const std::vector<double>& subcarrier_offsets_hz,
                                     const std::vector<gr_complex>& tx_weights)
    : d_tx(tx_elements_m),
      d_rx(rx_elements_m),
      d_carrier_hz(carrier_hz),
      d_offsets_hz(subcarrier_offsets_hz),
      d_tx_weights(tx_weights),
      d_uniform(true)
{
    check_positions(d_tx, "tx_elements_m");
    check_positions(d_rx, "rx_elements_m");
    if (!(std::isfinite(carrier_hz) && carrier_hz > 0))
        throw std::invalid_argument("carrier_hz must be a positive frequency");
    if (d_offsets_hz.size() < 2)
        throw std::invalid_argument("subcarrier_offsets_hz: at least two subcarriers are needed");
    for (size_t i = 0; i < d_offsets_hz.size(); i++) {
        if (!std::isfinite(d_offsets_hz[i]))
            throw std::invalid_argument("subcarrier_offsets_hz must be finite");
        if (i > 0 && !(d_offsets_hz[i] > d_offsets_hz[i - 1]))
            throw std::invalid_argument("subcarrier_offsets_hz must be strictly ascending");
    }
    if (d_tx_weights.empty())
        d_tx_weights.assign(d_tx.rows(), gr_complex(1.0f, 0.0f));
    if (static_cast<int>(d_tx_weights.size()) != d_tx.rows())
        throw std::invalid_argument("tx_weights: expected one weight per TX element (" +
                                    std::to_string(d_tx.rows()) + "), got " +
                                    std::to_string(d_tx_weights.size()));
    for (const auto& w : d_tx_weights)
        if (!std::isfinite(w.real()) || !std::isfinite(w.imag()))
            throw std::invalid_argument("tx_weights must be finite");
    const double step = subcarrier_spacing_hz();
    for (size_t i = 1; i < d_offsets_hz.size(); i++)
        if (std::abs((d_offsets_hz[i] - d_offsets_hz[i - 1]) - step) > 1e-6 * step)
            d_uniform = false;
}

radar_description::sptr radar_description::make(const positions_t& tx_elements_m,
                                                const positions_t& rx_elements_m,
                                                double carrier_hz,
                                                const std::vector<double>& subcarrier_offsets_hz,
                                                const std::vector<gr_complex>& tx_weights)
{
    return std::make_shared<radar_description>(
        tx_elements_m, rx_elements_m, carrier_hz, subcarrier_offsets_hz, tx_weights);
}

radar_description::sptr radar_description::make_uca_pair(int elements,
                                                         double radius_m,
                                                         double baseline_m,
                                                         double carrier_hz,
                                                         double bandwidth_hz,
                                                         int subcarriers,
                                                         double rotation_rad)
{
    if (!(baseline_m > 0))
        throw std::invalid_argument("baseline_m must be positive");
    return make(uca_positions(elements, radius_m, rotation_rad, -baseline_m / 2, 0.0),
                uca_positions(elements, radius_m, rotation_rad, +baseline_m / 2, 0.0),
                carrier_hz,
                uniform_subcarriers(subcarriers, bandwidth_hz));
}

radar_description::positions_t radar_description::uca_positions(
    int count, double radius_m, double rotation_rad, double centre_x_m, double centre_y_m)
{
    if (count < 1)
        throw std::invalid_argument("uca: element count must be at least 1");
    if (!(radius_m >= 0) || !std::isfinite(radius_m))
        throw std::invalid_argument("uca: radius_m must be a non-negative number");
    positions_t p(count, 2);
    for (int i = 0; i < count; i++) {
        const double phi = rotation_rad + 2.0 * M_PI * i / count;
        p(i, 0) = centre_x_m + radius_m * std::cos(phi);
        p(i, 1) = centre_y_m + radius_m * std::sin(phi);
    }
    return p;
}

radar_description::positions_t radar_description::ula_positions(
    int count, double spacing_m, double axis_rad, double centre_x_m, double centre_y_m)
{
    if (count < 1)
        throw std::invalid_argument("ula: element count must be at least 1");
    if (!(spacing_m > 0) || !std::isfinite(spacing_m))
        throw std::invalid_argument("ula: spacing_m must be positive");
    positions_t p(count, 2);
    for (int i = 0; i < count; i++) {
        const double s = (i - (count - 1) / 2.0) * spacing_m;
        p(i, 0) = centre_x_m + s * std::cos(axis_rad);
        p(i, 1) = centre_y_m + s * std::sin(axis_rad);
    }
    return p;
}

std::vector<double> radar_description::uniform_subcarriers(int count, double bandwidth_hz)
{
    if (count < 2)
        throw std::invalid_argument("uniform_subcarriers: at least two subcarriers are needed");
    if (!(bandwidth_hz > 0) || !std::isfinite(bandwidth_hz))
        throw std::invalid_argument("uniform_subcarriers: bandwidth_hz must be positive");
    std::vector<double> f(count);
    const double step = bandwidth_hz / count;
    for (int n = 0; n < count; n++)
        f[n] = (n - (count - 1) / 2.0) * step;
    return f;
}

Eigen::Vector2d radar_description::tx_centre_m() const
{
    return d_tx.colwise().mean().transpose();
}
Eigen::Vector2d radar_description::rx_centre_m() const
{
    return d_rx.colwise().mean().transpose();
}

double radar_description::subcarrier_spacing_hz() const
{
    return (d_offsets_hz.back() - d_offsets_hz.front()) / (d_offsets_hz.size() - 1);
}

double radar_description::baseline_m() const { return (tx_centre_m() - rx_centre_m()).norm(); }

double radar_description::direct_delay_s() const { return baseline_m() / speed_of_light_m_s; }

double radar_description::direct_aoa_rad() const
{
    const Eigen::Vector2d d = tx_centre_m() - rx_centre_m();
    double a = std::atan2(d.y(), d.x());
    if (a < 0)
        a += 2.0 * M_PI;
    return a;
}

std::string radar_description::to_string() const
{
    std::ostringstream s;
    s << "radar_description: " << num_tx() << " TX and " << num_rx()
      << " RX elements, baseline " << baseline_m() << " m, carrier " << d_carrier_hz / 1e6
      << " MHz, " << num_subcarriers() << " subcarriers spaced "
      << subcarrier_spacing_hz() / 1e3 << " kHz" << (d_uniform ? "" : " (non-uniform)");
    return s.str();
}

} // namespace thrumapper
} // namespace gr
