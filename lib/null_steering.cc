/* -*- c++ -*- */
/*
 * SPDX-License-Identifier: GPL-3.0-or-later
 */
#include "angles.h"
#include <gnuradio/thrumapper/null_steering.h>
#include <cmath>
#include <stdexcept>
#include <string>

namespace gr {
namespace thrumapper {

using cd = std::complex<double>;

null_steering::null_steering(radar_description::sptr radar) : d_radar(radar)
{
    if (!radar)
        throw std::invalid_argument("null_steering: a radar description is required");
    d_H = coupling_rows();
    // the coupling's directions in weight space, strongest first; the strongest is the beam
    // aimed at the receiver, the reference of every depth
    Eigen::SelfAdjointEigenSolver<Eigen::MatrixXcd> eig(d_H.adjoint() * d_H);
    d_coupling_dirs = eig.eigenvectors().rowwise().reverse();
    d_max_coupling = eig.eigenvalues().maxCoeff();
    // half-width of the plain beam's main lobe, to the -3 dB point
    const int K = radar->num_tx();
    const Eigen::VectorXcd a0 = far_field(0.0, radar->carrier_hz());
    d_halfwidth_rad = M_PI;
    for (int i = 1; i <= 1800; i++) {
        const double th = M_PI * i / 1800;
        const double g = std::norm(far_field(th, radar->carrier_hz()).dot(a0)) / (double(K) * K);
        if (g < 0.5) {
            d_halfwidth_rad = th;
            break;
        }
    }
}

Eigen::VectorXcd null_steering::far_field(double angle_rad, double freq_hz) const
{
    const auto& tx = d_radar->tx_elements_m();
    const Eigen::Vector2d c = d_radar->tx_centre_m();
    const double k = 2 * M_PI * freq_hz / speed_of_light_m_s;
    Eigen::VectorXcd a(tx.rows());
    for (int i = 0; i < tx.rows(); i++)
        a(i) = std::polar(1.0,
                          k * ((tx(i, 0) - c.x()) * std::cos(angle_rad) +
                               (tx(i, 1) - c.y()) * std::sin(angle_rad)));
    return a;
}

Eigen::MatrixXcd null_steering::coupling_rows() const
{
    const auto& tx = d_radar->tx_elements_m();
    const auto& rx = d_radar->rx_elements_m();
    const auto& df = d_radar->subcarrier_offsets_hz();
    const int K = tx.rows(), M = rx.rows(), N = df.size();
    Eigen::MatrixXcd H(M * N, K);
    for (int m = 0; m < M; m++)
        for (int k = 0; k < K; k++) {
            const double d = (tx.row(k) - rx.row(m)).norm();
            if (!(d > 0))
                throw std::invalid_argument("null_steering: a TX element sits on an RX element");
            for (int n = 0; n < N; n++) {
                const double f = d_radar->carrier_hz() + df[n];
                H(m * N + n, k) = std::polar(speed_of_light_m_s / (4 * M_PI * f * d),
                                             -2 * M_PI * f * d / speed_of_light_m_s);
            }
        }
    return H;
}

Eigen::VectorXcd null_steering::check_weights(const std::vector<gr_complex>& w) const
{
    if (static_cast<int>(w.size()) != d_radar->num_tx())
        throw std::invalid_argument("weights: expected " + std::to_string(d_radar->num_tx()) +
                                    " TX weights, got " + std::to_string(w.size()));
    Eigen::VectorXcd v(w.size());
    for (size_t i = 0; i < w.size(); i++) {
        if (!std::isfinite(w[i].real()) || !std::isfinite(w[i].imag()))
            throw std::invalid_argument("weights: weight " + std::to_string(i) + " is NaN or Inf");
        v(i) = cd(w[i].real(), w[i].imag());
    }
    if (v.squaredNorm() == 0)
        throw std::invalid_argument("weights: all weights are zero");
    return v;
}

static std::vector<gr_complex> to_weights(const Eigen::VectorXcd& w)
{
    const double scale = std::sqrt(double(w.size()) / w.squaredNorm());
    std::vector<gr_complex> out(w.size());
    for (int i = 0; i < w.size(); i++)
        out[i] = gr_complex(float(w(i).real() * scale), float(w(i).imag() * scale));
    return out;
}

std::vector<gr_complex> null_steering::eq9_weights(double main_lobe_rad, double null_rad) const
{
    if (!std::isfinite(main_lobe_rad) || !std::isfinite(null_rad))
        throw std::invalid_argument("eq9_weights: angles must be finite");
    const Eigen::VectorXcd ad = far_field(main_lobe_rad, d_radar->carrier_hz());
    const Eigen::VectorXcd an = far_field(null_rad, d_radar->carrier_hz());
    const Eigen::VectorXcd syn = ad - an * (an.dot(ad) / an.squaredNorm());
    if (syn.squaredNorm() < 1e-12 * ad.squaredNorm())
        throw std::invalid_argument("eq9_weights: the null is on the main lobe");
    return to_weights(syn.conjugate());
}

std::vector<gr_complex> null_steering::design(double main_lobe_rad,
                                              const std::vector<double>& null_angles_rad,
                                              bool null_receiver) const
{
    const int K = d_radar->num_tx();
    if (!std::isfinite(main_lobe_rad))
        throw std::invalid_argument("null_steering: main_lobe angle must be finite");
    const int max_nulls = K - 2;
    if (static_cast<int>(null_angles_rad.size()) > max_nulls)
        throw std::invalid_argument(
            "null_steering: " + std::to_string(null_angles_rad.size()) +
            " far-field nulls asked, but " + std::to_string(K) + " elements allow at most " +
            std::to_string(max_nulls) + " beside the main lobe and the receiver");
    for (double n : null_angles_rad) {
        if (!std::isfinite(n))
            throw std::invalid_argument("null_steering: null angles must be finite");
        if (angle_distance(n, main_lobe_rad) < d_halfwidth_rad)
            throw std::invalid_argument(
                "null_steering: a null at " + std::to_string(n * 180 / M_PI) +
                " deg is inside the main lobe (" + std::to_string(main_lobe_rad * 180 / M_PI) +
                " deg, half-width " + std::to_string(d_halfwidth_rad * 180 / M_PI) + " deg)");
    }
    if (null_receiver && angle_distance(receiver_bearing_rad(), main_lobe_rad) < d_halfwidth_rad)
        throw std::invalid_argument("null_steering: the receiver (bearing " +
                                    std::to_string(receiver_bearing_rad() * 180 / M_PI) +
                                    " deg) is inside the main lobe; steer the main lobe away");

    // Least squares: the weights nearest the plain beam toward the main lobe that are
    // orthogonal to the far-field nulls' steering vectors (exact zeros at the carrier) and to
    // the r strongest directions of the exact near-field coupling to the receiver over the
    // band, with r the fewest that reach the target depth. The coupling's directions fall off
    // fast (at 0.7 m: 1, 5e-2, 2e-3, 2e-4, 5e-5, 8e-7, ...), so a few of the K degrees of
    // freedom buy a deep null and the main lobe loses about 1 dB.
    const Eigen::VectorXcd beam = far_field(main_lobe_rad, d_radar->carrier_hz()).conjugate();
    Eigen::MatrixXcd fixed(K, null_angles_rad.size());
    for (size_t i = 0; i < null_angles_rad.size(); i++)
        fixed.col(i) = far_field(null_angles_rad[i], d_radar->carrier_hz()).conjugate();
    const int free_dims = K - 1 - int(null_angles_rad.size());
    // main-lobe gain |a(θ)ᵀw|²/‖w‖² of the plain beam (K); no receiver direction is bought
    // with more than 3 dB of it
    const double plain_gain = beam.squaredNorm();
    auto gain = [&](const Eigen::VectorXcd& v) { return std::norm(beam.dot(v)) / v.squaredNorm(); };
    Eigen::VectorXcd w;
    for (int r = 0; r <= (null_receiver ? free_dims : 0); r++) {
        Eigen::MatrixXcd avoid(K, fixed.cols() + r);
        avoid << fixed, d_coupling_dirs.leftCols(r);
        Eigen::VectorXcd v = beam;
        if (avoid.cols() > 0) {
            const Eigen::HouseholderQR<Eigen::MatrixXcd> qr(avoid);
            const Eigen::MatrixXcd Q = qr.householderQ() * Eigen::MatrixXcd::Identity(K, avoid.cols());
            v -= Q * (Q.adjoint() * v);
        }
        if (v.norm() < 1e-9 * beam.norm()) {
            if (r == 0)
                throw std::invalid_argument("null_steering: the nulls leave no main lobe");
            break;
        }
        if (r > 0 && gain(v) < 0.5 * plain_gain)
            break;
        w = v;
        if (!null_receiver || depth_db(w) <= d_target_depth_db)
            break;
    }
    return to_weights(w);
}

double null_steering::depth_db(const Eigen::VectorXcd& w) const
{
    const double p = (d_H * w).squaredNorm() / (d_max_coupling * w.squaredNorm());
    return 10 * std::log10(std::max(p, 1e-30));
}

void null_steering::set_target_depth(double depth_db)
{
    if (!(depth_db < 0) || !std::isfinite(depth_db))
        throw std::invalid_argument("null_steering: the target null depth must be a negative dB value");
    d_target_depth_db = depth_db;
}

double null_steering::coupling_db(const std::vector<gr_complex>& weights) const
{
    return depth_db(check_weights(weights));
}

double null_steering::expected_coupling_db(const std::vector<gr_complex>& weights,
                                           double phase_error_rad) const
{
    const Eigen::VectorXcd w = check_weights(weights);
    if (!(phase_error_rad >= 0) || !std::isfinite(phase_error_rad))
        throw std::invalid_argument("phase_error_rad must be a non-negative rms");
    const double coherent = std::exp(-phase_error_rad * phase_error_rad);
    double p = 0;
    for (int r = 0; r < d_H.rows(); r++) {
        const Eigen::VectorXcd hw = d_H.row(r).transpose().cwiseProduct(w);
        p += std::norm(hw.sum()) * coherent + hw.squaredNorm() * (1 - coherent);
    }
    p /= d_max_coupling * w.squaredNorm();
    return 10 * std::log10(std::max(p, 1e-30));
}

Eigen::MatrixXd null_steering::beam_pattern_db(const std::vector<gr_complex>& weights,
                                               const std::vector<double>& angles_rad,
                                               const std::vector<double>& frequencies_hz) const
{
    const Eigen::VectorXcd w = check_weights(weights);
    Eigen::MatrixXd g(frequencies_hz.size(), angles_rad.size());
    for (size_t i = 0; i < frequencies_hz.size(); i++)
        for (size_t j = 0; j < angles_rad.size(); j++) {
            const cd r = far_field(angles_rad[j], frequencies_hz[i]).transpose() * w;
            g(i, j) = 10 * std::log10(std::max(std::norm(r) / w.squaredNorm(), 1e-30));
        }
    return g;
}

double null_steering::receiver_bearing_rad() const
{
    const Eigen::Vector2d d = d_radar->rx_centre_m() - d_radar->tx_centre_m();
    double a = std::atan2(d.y(), d.x());
    return a < 0 ? a + 2 * M_PI : a;
}

double null_steering::specular_bearing_rad(double standoff_m) const
{
    const Eigen::Vector2d t = d_radar->tx_centre_m(), r = d_radar->rx_centre_m();
    const Eigen::Vector2d b = r - t;
    const Eigen::Vector2d left(-b.y() / b.norm(), b.x() / b.norm());
    const Eigen::Vector2d p = 0.5 * (t + r) + standoff_m * left;
    double a = std::atan2(p.y() - t.y(), p.x() - t.x());
    return a < 0 ? a + 2 * M_PI : a;
}

} // namespace thrumapper
} // namespace gr
