/* -*- c++ -*- */
/*
 * SPDX-License-Identifier: GPL-3.0-or-later
 */
#ifndef INCLUDED_THRUMAPPER_MANIFOLD_H
#define INCLUDED_THRUMAPPER_MANIFOLD_H

#include <gnuradio/thrumapper/api.h>
#include <gnuradio/thrumapper/radar_description.h>
#include <Eigen/Dense>
#include <vector>

namespace gr {
namespace thrumapper {

/*!
 * \brief Array and delay manifolds (steering vectors), FORMATS.md conventions.
 * \ingroup thrumapper
 *
 * A path of delay τ arriving at the array from bearing θ (CCW from robot +x) puts
 * exp(-j2π f (τ - p_m·u(θ)/c)) on element m at position p_m relative to the array centre,
 * u(θ) = [cos θ, sin θ]. The far-field steering vector is therefore
 * a_m(θ) = exp(+j 2π f p_m·u(θ)/c), and the delay manifold g_n(τ) = exp(-j2π Δf_n τ).
 */

//! Far-field (plane-wave) steering vector at frequency freq_hz, relative to the array centre.
THRUMAPPER_API Eigen::VectorXcd steering_far_field(const radar_description::positions_t& elements_m,
                                                   double aoa_rad,
                                                   double freq_hz);

/*!
 * \brief Near-field (spherical) steering vector toward a point source at source_m.
 *
 * Element m gets (d_0/d_m)·exp(-j2π f (d_m - d_0)/c), with d_m = |p_m - source| and d_0
 * the distance from the array centre: the exact wavefront, phase-referenced to the centre
 * like the far-field vector, to which it tends as the source recedes.
 */
THRUMAPPER_API Eigen::VectorXcd steering_near_field(const radar_description::positions_t& elements_m,
                                                    const Eigen::Vector2d& source_m,
                                                    double freq_hz);

//! Delay manifold g_n(τ) = exp(-j2π Δf_n τ) over the given subcarrier offsets.
THRUMAPPER_API Eigen::VectorXcd delay_manifold(const std::vector<double>& subcarrier_offsets_hz,
                                               double delay_s);

/*!
 * \brief Space-time manifold u(θ, τ) = a(θ) ⊗ g(τ) (paper eq. 5), far field at the carrier,
 * element-major: entry m·N + n, the CSI layout of the module.
 */
THRUMAPPER_API Eigen::VectorXcd space_time_manifold(const radar_description& radar,
                                                    double aoa_rad,
                                                    double delay_s);

/*!
 * \brief Exact wideband near-field response of the direct TX→RX coupling, M×N element-major,
 * for the given TX weights and extra (system) delay, free space between isotropic elements:
 * Σ_k w_k λ_n/(4π d_km) exp(-j2π f_n (d_km/c + τ_sys)), f_n = fc + Δf_n, d_km = |t_k - r_m|.
 */
THRUMAPPER_API Eigen::VectorXcd direct_path_response(const radar_description& radar,
                                                     const std::vector<gr_complex>& tx_weights,
                                                     double system_delay_s);

} // namespace thrumapper
} // namespace gr

#endif
