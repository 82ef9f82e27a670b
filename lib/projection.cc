/* -*- c++ -*- */
/*
 * SPDX-License-Identifier: GPL-3.0-or-later
 */
#include <gnuradio/thrumapper/manifold.h>
#include <gnuradio/thrumapper/projection.h>
#include <cmath>
#include <stdexcept>
#include <string>

namespace gr {
namespace thrumapper {

path_projector::path_projector(radar_description::sptr radar)
    : d_radar(radar), d_system_delay_s(0), d_direct(false)
{
    if (!radar)
        throw std::invalid_argument("path_projector: a radar description is required");
    d_Q.resize(radar->num_rx() * radar->num_subcarriers(), 0);
}

void path_projector::set_system_delay(double system_delay_s)
{
    if (!std::isfinite(system_delay_s))
        throw std::invalid_argument("system_delay_s must be finite");
    d_system_delay_s = system_delay_s;
    rebuild();
}

void path_projector::set_paths(const std::vector<double>& aoa_rad, const std::vector<double>& delay_s)
{
    if (aoa_rad.size() != delay_s.size())
        throw std::invalid_argument("path_projector: " + std::to_string(aoa_rad.size()) +
                                    " angles but " + std::to_string(delay_s.size()) + " delays");
    for (size_t i = 0; i < aoa_rad.size(); i++)
        if (!std::isfinite(aoa_rad[i]) || !std::isfinite(delay_s[i]))
            throw std::invalid_argument("path_projector: path " + std::to_string(i) +
                                        " has a NaN or Inf angle or delay");
    const int max_paths = d_radar->num_rx() * d_radar->num_subcarriers() / 2;
    if (static_cast<int>(aoa_rad.size()) > max_paths)
        throw std::invalid_argument("path_projector: too many paths to cancel");
    d_aoa = aoa_rad;
    d_delay = delay_s;
    rebuild();
}

void path_projector::set_direct_path(bool cancel, const std::vector<gr_complex>& tx_weights)
{
    if (!tx_weights.empty()) {
        if (static_cast<int>(tx_weights.size()) != d_radar->num_tx())
            throw std::invalid_argument("path_projector: expected " +
                                        std::to_string(d_radar->num_tx()) + " TX weights, got " +
                                        std::to_string(tx_weights.size()));
        for (const auto& w : tx_weights)
            if (!std::isfinite(w.real()) || !std::isfinite(w.imag()))
                throw std::invalid_argument("path_projector: TX weights must be finite");
    }
    d_direct = cancel;
    d_weights = tx_weights;
    rebuild();
}

void path_projector::clear()
{
    d_aoa.clear();
    d_delay.clear();
    d_direct = false;
    rebuild();
}

void path_projector::rebuild()
{
    const int MN = d_radar->num_rx() * d_radar->num_subcarriers();
    const int P = d_aoa.size() + (d_direct ? 1 : 0);
    if (P == 0) {
        d_Q.resize(MN, 0);
        return;
    }
    Eigen::MatrixXcd A(MN, P);
    for (size_t p = 0; p < d_aoa.size(); p++)
        A.col(p) = space_time_manifold(*d_radar, d_aoa[p], d_delay[p] + d_system_delay_s);
    if (d_direct)
        A.col(P - 1) = direct_path_response(*d_radar, d_weights, d_system_delay_s);
    // column pivoting finds the rank: two paths at one point are one direction
    Eigen::ColPivHouseholderQR<Eigen::MatrixXcd> qr(A);
    qr.setThreshold(1e-10);
    const int rank = qr.rank();
    d_Q = qr.householderQ() * Eigen::MatrixXcd::Identity(MN, rank);
}

Eigen::MatrixXcd path_projector::projector() const
{
    const int MN = d_Q.rows();
    return Eigen::MatrixXcd::Identity(MN, MN) - d_Q * d_Q.adjoint();
}

Eigen::MatrixXcd path_projector::apply_matrix(const Eigen::MatrixXcd& frames) const
{
    const int M = d_radar->num_rx(), N = d_radar->num_subcarriers();
    if (frames.cols() != N || frames.rows() % M != 0 || frames.rows() == 0)
        throw std::invalid_argument("path_projector: expected frames of " + std::to_string(M) +
                                    " x " + std::to_string(N));
    Eigen::MatrixXcd out = frames;
    if (d_Q.cols() == 0)
        return out;
    const int F = frames.rows() / M;
    Eigen::VectorXcd h(M * N);
    for (int f = 0; f < F; f++) {
        for (int m = 0; m < M; m++)
            h.segment(m * N, N) = frames.row(f * M + m).transpose();
        h -= d_Q * (d_Q.adjoint() * h);
        for (int m = 0; m < M; m++)
            out.row(f * M + m) = h.segment(m * N, N).transpose();
    }
    return out;
}

void path_projector::apply(const std::complex<float>* in, std::complex<float>* out, int num_frames) const
{
    const int MN = d_Q.rows();
    if (d_Q.cols() == 0) {
        if (in != out)
            std::copy(in, in + size_t(MN) * num_frames, out);
        return;
    }
    Eigen::VectorXcd h(MN);
    for (int f = 0; f < num_frames; f++) {
        for (int i = 0; i < MN; i++)
            h(i) = std::complex<double>(in[size_t(f) * MN + i]);
        h -= d_Q * (d_Q.adjoint() * h);
        for (int i = 0; i < MN; i++)
            out[size_t(f) * MN + i] = std::complex<float>(h(i));
    }
}

} // namespace thrumapper
} // namespace gr
