/* -*- c++ -*- */
/*
 * SPDX-License-Identifier: GPL-3.0-or-later
 */
#ifndef INCLUDED_THRUMAPPER_PROJECTION_H
#define INCLUDED_THRUMAPPER_PROJECTION_H

#include <gnuradio/thrumapper/api.h>
#include <gnuradio/thrumapper/radar_description.h>
#include <Eigen/Dense>
#include <complex>
#include <vector>

namespace gr {
namespace thrumapper {

/*!
 * \brief Cancels known paths from CSI frames by projection (paper §2.3.2, eq. 10).
 * \ingroup thrumapper
 *
 * A = [u(θ_1, τ_1), …] holds the space-time manifold vectors of the paths to remove (far
 * field, element-major, over all N subcarriers) and, optionally, the exact near-field
 * wideband response of the direct TX→RX path for the given TX weights; Q is the orthonormal
 * basis of A's columns (Householder QR, dependent columns dropped), and each frame h becomes
 * h - Q Qᴴ h: its projection onto the orthogonal complement of the cancelled paths.
 *
 * The projection acts on the whole M·N frame rather than on the smoothed M·L snapshots: it
 * removes the same paths from every smoothed snapshot (each is a window of the frame), and the
 * longer vectors overlap less with the paths that are kept. The direct path needs this: its
 * near-field response is one vector of the frame but not of a smoothing window.
 *
 * Delays follow FORMATS.md (system delay removed): set the system delay first.
 */
class THRUMAPPER_API path_projector
{
public:
    explicit path_projector(radar_description::sptr radar);

    void set_system_delay(double system_delay_s);
    //! Far-field paths to cancel: angles (rad) and delays (s), equal lengths.
    void set_paths(const std::vector<double>& aoa_rad, const std::vector<double>& delay_s);
    //! Cancel the direct path too, with its exact response for these TX weights (empty: the radar's).
    void set_direct_path(bool cancel, const std::vector<gr_complex>& tx_weights = {});
    void clear();

    //! The number of independent directions cancelled.
    int rank() const { return d_Q.cols(); }
    const Eigen::MatrixXcd& basis() const { return d_Q; }
    //! The M·N × M·N projector I - Q Qᴴ (for tests and analysis; apply() never forms it).
    Eigen::MatrixXcd projector() const;

    //! out = projection of in, for num_frames frames of M·N values; in may equal out.
    void apply(const std::complex<float>* in, std::complex<float>* out, int num_frames) const;
    //! The same on (F·M) × N frames (rows frame-major).
    Eigen::MatrixXcd apply_matrix(const Eigen::MatrixXcd& frames) const;

    double system_delay() const { return d_system_delay_s; }
    const std::vector<double>& aoa_rad() const { return d_aoa; }
    const std::vector<double>& delay_s() const { return d_delay; }
    bool cancels_direct_path() const { return d_direct; }

private:
    void rebuild();

    radar_description::sptr d_radar;
    double d_system_delay_s;
    std::vector<double> d_aoa, d_delay;
    bool d_direct;
    std::vector<gr_complex> d_weights;
    Eigen::MatrixXcd d_Q;
};

} // namespace thrumapper
} // namespace gr

#endif
