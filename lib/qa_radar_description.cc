/* -*- c++ -*- */
/*
 * SPDX-License-Identifier: GPL-3.0-or-later
 */
#include <gnuradio/thrumapper/manifold.h>
#include <gnuradio/thrumapper/radar_description.h>
#include <boost/test/unit_test.hpp>
#include <cmath>

using namespace gr::thrumapper;

BOOST_AUTO_TEST_CASE(uca_pair_geometry)
{
    auto r = radar_description::make_uca_pair(8, 0.08, 0.7, 2.44e9, 120e6, 128);
    BOOST_CHECK_EQUAL(r->num_tx(), 8);
    BOOST_CHECK_EQUAL(r->num_rx(), 8);
    BOOST_CHECK_EQUAL(r->num_subcarriers(), 128);
    BOOST_CHECK_CLOSE(r->baseline_m(), 0.7, 1e-9);
    // the RX array sits ahead (+x) of the TX array: the TX is behind the RX, at 180°
    BOOST_CHECK_CLOSE(r->direct_aoa_rad(), M_PI, 1e-9);
    BOOST_CHECK_CLOSE(r->direct_delay_s(), 0.7 / speed_of_light_m_s, 1e-9);
    // every element at the radius from its centre; neighbours 2r sin(π/8) apart
    for (int i = 0; i < 8; i++) {
        const Eigen::Vector2d p = r->rx_elements_m().row(i).transpose() - r->rx_centre_m();
        BOOST_CHECK_CLOSE(p.norm(), 0.08, 1e-9);
    }
    const double spacing = (r->rx_elements_m().row(1) - r->rx_elements_m().row(0)).norm();
    BOOST_CHECK_CLOSE(spacing, 2 * 0.08 * std::sin(M_PI / 8), 1e-9);
    BOOST_CHECK(r->uniform_spacing());
    BOOST_CHECK_CLOSE(r->subcarrier_spacing_hz(), 120e6 / 128, 1e-9);
    // centred subcarriers: the band is symmetric about the carrier
    BOOST_CHECK_SMALL(r->subcarrier_offsets_hz().front() + r->subcarrier_offsets_hz().back(), 1e-3);
}

BOOST_AUTO_TEST_CASE(bad_descriptions_throw)
{
    auto tx = radar_description::uca_positions(8, 0.08);
    auto rx = radar_description::uca_positions(8, 0.08, 0, 0.7, 0);
    auto f = radar_description::uniform_subcarriers(64, 120e6);
    BOOST_CHECK_THROW(radar_description::make(tx, rx, -1.0, f), std::invalid_argument);
    std::vector<double> descending(f.rbegin(), f.rend());
    BOOST_CHECK_THROW(radar_description::make(tx, rx, 2.4e9, descending), std::invalid_argument);
    std::vector<gr_complex> w(7, gr_complex(1, 0));
    BOOST_CHECK_THROW(radar_description::make(tx, rx, 2.4e9, f, w), std::invalid_argument);
    w.assign(8, gr_complex(NAN, 0));
    BOOST_CHECK_THROW(radar_description::make(tx, rx, 2.4e9, f, w), std::invalid_argument);
    BOOST_CHECK_THROW(radar_description::uca_positions(0, 0.1), std::invalid_argument);
}

BOOST_AUTO_TEST_CASE(near_field_tends_to_far_field)
{
    auto rx = radar_description::uca_positions(8, 0.08);
    const double f = 2.44e9, th = 0.7;
    const Eigen::VectorXcd a = steering_far_field(rx, th, f);
    // a source 1 km away along θ: the spherical wavefront is a plane wave to 1e-4 rad
    const Eigen::Vector2d far(1000 * std::cos(th), 1000 * std::sin(th));
    const Eigen::VectorXcd b = steering_near_field(rx, far, f);
    for (int m = 0; m < 8; m++)
        BOOST_CHECK_SMALL(std::abs(std::arg(b(m) / a(m))), 1e-3);
    // at 0.7 m the wavefront curvature is far from a plane: the phase error exceeds 10°
    const Eigen::Vector2d near(0.7 * std::cos(th), 0.7 * std::sin(th));
    const Eigen::VectorXcd c = steering_near_field(rx, near, f);
    double worst = 0;
    for (int m = 0; m < 8; m++)
        worst = std::max(worst, std::abs(std::arg(c(m) / a(m))));
    BOOST_CHECK_GT(worst, 10 * M_PI / 180);
}

BOOST_AUTO_TEST_CASE(direct_path_delay_from_geometry)
{
    // One TX and one RX element 0.7 m apart: the response's phase slope over frequency is
    // the distance over c, plus the system delay.
    radar_description::positions_t tx(1, 2), rx(1, 2);
    tx << 0, 0;
    rx << 0.7, 0;
    auto r = radar_description::make(tx, rx, 2.44e9, radar_description::uniform_subcarriers(64, 120e6));
    const double tsys = 12.5e-9;
    const Eigen::VectorXcd h = direct_path_response(*r, {}, tsys);
    const double dphi = std::arg(h(33) / h(32));
    const double tau = -dphi / (2 * M_PI * r->subcarrier_spacing_hz());
    // aliasing: the phase step is modulo 2π, so compare modulo 1/Δf
    const double period = 1.0 / r->subcarrier_spacing_hz();
    double diff = tau - (0.7 / speed_of_light_m_s + tsys);
    diff -= period * std::round(diff / period);
    BOOST_CHECK_SMALL(diff, 1e-13);
    // free-space amplitude λ/(4πd) at the lowest subcarrier
    const double f0 = 2.44e9 + r->subcarrier_offsets_hz()[0];
    BOOST_CHECK_CLOSE(std::abs(h(0)), speed_of_light_m_s / (4 * M_PI * f0 * 0.7), 1e-9);
}
