/* -*- c++ -*- */
/*
 * SPDX-License-Identifier: GPL-3.0-or-later
 */
#ifndef INCLUDED_THRUMAPPER_NULL_STEERING_H
#define INCLUDED_THRUMAPPER_NULL_STEERING_H

#include <gnuradio/thrumapper/api.h>
#include <gnuradio/thrumapper/radar_description.h>
#include <Eigen/Dense>
#include <vector>

namespace gr {
namespace thrumapper {

/*!
 * \brief TX weights with a main lobe toward the walls and nulls toward the receiver and
 * corners (paper §2.3.1, eq. 9, and the LCMV several-null design it left as future work).
 * \ingroup thrumapper
 *
 * Conventions: TX element k sends w_k·s. The far field toward bearing θ (CCW from robot +x,
 * seen from the TX centre) is Σ_k w_k exp(+j2πf p_k·u(θ)/c) = a(θ)ᵀw. The receiver is
 * near-field (0.7 m): its coupling to RX element m at frequency f is
 * Σ_k w_k λ/(4π d_km) exp(-j2πf d_km/c), exact, over the whole band.
 *
 * Weights are scaled to the total power of all-ones weights (‖w‖² = K). The coupling (null
 * depth) is the direct coupling power, summed over the RX elements and the subcarriers,
 * relative to the most any weights of the same power can couple (a beam aimed at the
 * receiver).
 */
class THRUMAPPER_API null_steering
{
public:
    explicit null_steering(radar_description::sptr radar);

    /*!
     * \brief The paper's eq. 9 with plane-wave steering vectors at the carrier:
     * a_syn = a(θ_d) - a(θ_n) a(θ_n)ᴴa(θ_d)/a(θ_n)ᴴa(θ_n), w = conj(a_syn).
     */
    std::vector<gr_complex> eq9_weights(double main_lobe_rad, double null_rad) const;

    /*!
     * \brief Several nulls with a main-lobe constraint, least squares: the weights nearest the
     * plain beam toward main_lobe_rad that have exact zeros toward each far-field null
     * (corners) and, when null_receiver, are orthogonal to the strongest directions of the
     * exact near-field coupling to every RX element across the band — as many as reach the
     * target depth (default -45 dB, below what 2° rms phase error allows), and never so many
     * that the main lobe loses more than 3 dB.
     * Throws std::invalid_argument for a null inside the main lobe (closer than
     * main_lobe_halfwidth_rad()), more nulls than the K-1 degrees of freedom, NaN angles.
     */
    std::vector<gr_complex> design(double main_lobe_rad,
                                   const std::vector<double>& null_angles_rad,
                                   bool null_receiver = true) const;

    //! The receiver null depth design() aims for, dB (negative; default -45).
    void set_target_depth(double depth_db);
    double target_depth() const { return d_target_depth_db; }

    //! Half-width of the main lobe: from its peak to the -3 dB point of the plain beam.
    double main_lobe_halfwidth_rad() const { return d_halfwidth_rad; }

    //! Direct coupling power relative to a beam of equal power aimed at the receiver, dB.
    double coupling_db(const std::vector<gr_complex>& weights) const;

    /*!
     * \brief Expected coupling (dB, as coupling_db) when each weight's phase has an
     * independent zero-mean Gaussian error of the given rms: with E[e^{jφ}] = e^{-σ²/2},
     * E|Σ_k h_k w_k e^{jφ_k}|² = |Σ h_k w_k|² e^{-σ²} + Σ|h_k w_k|² (1 - e^{-σ²}).
     */
    double expected_coupling_db(const std::vector<gr_complex>& weights, double phase_error_rad) const;

    /*!
     * \brief Far-field array gain |a(θ, f)ᵀw|² / ‖w‖² in dB (8 elements: at most 9 dB),
     * rows: the frequencies, columns: the angles.
     */
    Eigen::MatrixXd beam_pattern_db(const std::vector<gr_complex>& weights,
                                    const std::vector<double>& angles_rad,
                                    const std::vector<double>& frequencies_hz) const;

    //! Bearing of the RX centre seen from the TX centre (radians, robot frame).
    double receiver_bearing_rad() const;

    /*!
     * \brief Bearing from the TX centre of the specular point of a wall parallel to the
     * baseline at the given stand-off, on the side given by the sign (negative: the right).
     * The main lobe must cover it: atan(s / (b/2)) from the baseline, not broadside.
     */
    double specular_bearing_rad(double standoff_m) const;

    radar_description::sptr radar() const { return d_radar; }

private:
    Eigen::VectorXcd far_field(double angle_rad, double freq_hz) const; // a(θ) at the TX
    Eigen::MatrixXcd coupling_rows() const; // (M·Nf) × K rows h_mf
    Eigen::VectorXcd check_weights(const std::vector<gr_complex>& w) const;
    double depth_db(const Eigen::VectorXcd& w) const;

    radar_description::sptr d_radar;
    Eigen::MatrixXcd d_H;       // coupling rows over RX elements and band samples
    Eigen::MatrixXcd d_coupling_dirs; // eigenvectors of HᴴH, strongest first
    double d_max_coupling;      // its largest eigenvalue
    double d_target_depth_db = -45.0;
    double d_halfwidth_rad;
};

} // namespace thrumapper
} // namespace gr

#endif
