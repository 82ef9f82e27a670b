/* -*- c++ -*- */
/*
 * SPDX-License-Identifier: GPL-3.0-or-later
 */
#ifndef INCLUDED_THRUMAPPER_SLAB_ECHO_H
#define INCLUDED_THRUMAPPER_SLAB_ECHO_H

#include <gnuradio/thrumapper/api.h>
#include <Eigen/Dense>
#include <complex>
#include <vector>

namespace gr {
namespace thrumapper {

/*!
 * \brief The CSI of one wall's specular echo, element pair by element pair (the core of
 * echo_model.EchoModel.echo_csi).
 * \ingroup thrumapper
 *
 * For every TX element k and RX element m the echo is built by the image method: the TX
 * element mirrored in the wall's face, the exact path length L_km to the RX element
 * (spherical wavefronts), the wall's reflection coefficient Γ at that pair's own
 * incidence angle and every subcarrier's absolute frequency, and the insertion
 * transmission T of every wall a leg crosses (TX → bounce, bounce → RX), at that leg's
 * incidence:
 *
 *   h[m, n] = λ_n · Σ_k w_k · Γ(θ_km, f_n) · Π T(θ_leg, f_n) · e^{−j2π f_n L_km / c} /
 * (4π L_km)
 *
 * with the system delay left out (robot frame, FORMATS.md's channel). Γ and T come from
 * coefficient tables made once per material (rows: incidence angles 0..90° on a uniform
 * grid, columns: the subcarriers; building_sim.coefficient_table), interpolated linearly
 * in the angle. The CSI fits of a map evaluate this ~10⁵ times, which is why it is C++:
 * on uniform subcarriers the phase ramp over the band is made of two sines and cosines a
 * pair (the first subcarrier's phase, the step) and products, instead of one each
 * subcarrier.
 */
class THRUMAPPER_API slab_echo
{
public:
    using table_type = Eigen::
        Matrix<std::complex<double>, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;

    /*!
     * \param tx_elements_m (K, 2) TX element positions, robot frame, metres
     * \param rx_elements_m (M, 2) RX element positions
     * \param carrier_hz the carrier
     * \param subcarrier_offsets_hz (N) subcarrier offsets from the carrier
     */
    slab_echo(const Eigen::MatrixXd& tx_elements_m,
              const Eigen::MatrixXd& rx_elements_m,
              double carrier_hz,
              const std::vector<double>& subcarrier_offsets_hz);

    /*!
     * Registers a coefficient table (Γ or T of one material): (A, N), row i at incidence
     * i/(A−1)·90°, A ≥ 2. Returns its id for echo().
     */
    int add_table(const table_type& table);

    /*!
     * (M, N) CSI of the echo of the wall whose face passes through face_point_m with
     * normal `normal` (any length, not zero), robot frame. \param gamma_table id of the
     * wall's Γ table, or −1 for a perfect conductor (Γ = −1) \param tx_weights (K) the TX
     * weights \param crossed_points_m (C, 2) a point of each crossed wall's face \param
     * crossed_normals (C, 2) their normals \param crossed_tables (C) their T tables' ids
     * (−1: the wall is ignored)
     */
    table_type echo(const Eigen::Vector2d& face_point_m,
                    const Eigen::Vector2d& normal,
                    int gamma_table,
                    const Eigen::VectorXcd& tx_weights,
                    const Eigen::MatrixXd& crossed_points_m,
                    const Eigen::MatrixXd& crossed_normals,
                    const std::vector<int>& crossed_tables) const;

    /*!
     * (M, N) CSI of the double bounce TX → face 1 → face 2 → RX between two infinite
     * faces (a corridor's walls facing each other), by imaging each TX element in face 1
     * and then in face 2: Γ at both bounces' incidences (gamma_table −1: two conductor
     * bounces, +1). A pair whose bounces fall behind a focus or on a face's back adds
     * nothing.
     */
    table_type double_echo(const Eigen::Vector2d& first_point_m,
                           const Eigen::Vector2d& first_normal,
                           const Eigen::Vector2d& second_point_m,
                           const Eigen::Vector2d& second_normal,
                           int gamma_table,
                           const Eigen::VectorXcd& tx_weights) const;

    /*!
     * (M, N) CSI of a concave corner's double bounce, both orders (TX → face a → face b →
     * RX and TX → b → a → RX): the faces are half-lines from corner_m, each running into
     * the side the other faces (a room's inside corner), normals into the room. A pair
     * whose bounce points fall off either face, or whose arrays are not in front of both
     * faces, adds nothing.
     */
    table_type corner_echo(const Eigen::Vector2d& corner_m,
                           const Eigen::Vector2d& normal_a,
                           const Eigen::Vector2d& normal_b,
                           int gamma_table,
                           const Eigen::VectorXcd& tx_weights) const;

    //! A complex matrix of any layout, seen without a copy (numpy's arrays from Python).
    using cmatrix_ref = Eigen::
        Ref<const Eigen::MatrixXcd, 0, Eigen::Stride<Eigen::Dynamic, Eigen::Dynamic>>;

    /*!
     * The CSI fit's objective for trial placements of one wall at one pose (the core of
     * wall_refinement.CsiWallRefiner._fit): for each trial (offset_m, rotation_rad) the
     * wall is turned by the rotation about pivot_m and then moved offset_m along its new
     * normal, and J is the energy of the data `rows` (F, M·N; already projected away from
     * `basis`) that the trial's echo captures with a free gain per frame, the echo
     * projected away from `basis` too (M·N, B orthonormal columns; B = 0: none). A trial
     * the pose does not see scores 0: both array centres must be in front of its face,
     * its specular point (between the array centres) within t_min_m..t_max_m along the
     * direction (−n_y, n_x) from its centre, and the robot on its normal's side.
     *
     * World frame: pose (x, y, heading); the wall's centre and unit normal; pivot_m. The
     * echo is echo()'s in the pose's robot frame, times system_response (N) per
     * subcarrier, flattened row by row (m·N + n). Each leg from the TX centre to the
     * specular point and from there to the RX centre that properly crosses a blocker
     * segment (blocker_ends_m (C, 4): a_x, a_y, b_x, b_y) takes that blocker's face
     * (blocker_points_m, blocker_normals (C, 2)) with T table blocker_table into the
     * echo, in the blockers' order.
     */
    Eigen::VectorXd trial_energies(const Eigen::Vector3d& pose,
                                   const Eigen::Vector2d& tx_centre_m,
                                   const Eigen::Vector2d& rx_centre_m,
                                   const Eigen::Vector2d& wall_centre_m,
                                   const Eigen::Vector2d& wall_normal,
                                   double t_min_m,
                                   double t_max_m,
                                   const Eigen::Vector2d& pivot_m,
                                   const Eigen::MatrixXd& trials,
                                   int gamma_table,
                                   const Eigen::VectorXcd& tx_weights,
                                   const Eigen::MatrixXd& blocker_ends_m,
                                   const Eigen::MatrixXd& blocker_points_m,
                                   const Eigen::MatrixXd& blocker_normals,
                                   int blocker_table,
                                   const Eigen::VectorXcd& system_response,
                                   const cmatrix_ref& basis,
                                   const cmatrix_ref& rows) const;

    int num_tx() const { return d_tx.rows(); }
    int num_rx() const { return d_rx.rows(); }
    int num_subcarriers() const { return static_cast<int>(d_k.size()); }
    //! Whether the subcarriers are evenly spaced (the fast phase ramp) or not (one
    //! sin/cos each).
    bool uniform_subcarriers() const { return d_uniform; }

private:
    void check_table(int id, const char* what) const;
    // g[n] *= table(cos_incidence)[n], linear in the angle
    void multiply_by(std::complex<double>* g, int id, double cos_incidence) const;
    // e[n] = e^{−j k_n L}
    void phase_ramp(double length_m, std::complex<double>* e) const;
    // row[n] += scale · g[n] · e^{−j k_n L} (g, e: work buffers of N)
    void add_path(double length_m,
                  std::complex<double> scale,
                  std::complex<double>* g,
                  std::complex<double>* e,
                  std::complex<double>* row) const;
    // The double bounces TX → (q1, n1) → (q2, n2) → RX of the pairs `valid` accepts,
    // added to out; valid(k, m, first bounce, second bounce) sees the bounce points
    template <typename Valid>
    void add_doubles(const Eigen::Vector2d& q1,
                     const Eigen::Vector2d& n1,
                     const Eigen::Vector2d& q2,
                     const Eigen::Vector2d& n2,
                     int gamma_table,
                     const Eigen::VectorXcd& tx_weights,
                     Valid valid,
                     table_type& out) const;
    void check_weights(const Eigen::VectorXcd& tx_weights) const;
    // out[m, n] *= λ_n (the aperture of an isotropic element at each subcarrier)
    void scale_by_wavelength(table_type& out) const;

    Eigen::MatrixX2d d_tx, d_rx;
    std::vector<double> d_k;      // wavenumbers 2π f_n / c
    std::vector<double> d_lambda; // wavelengths c / f_n
    double d_dk;                  // the wavenumber step on uniform subcarriers
    bool d_uniform;
    std::vector<table_type> d_tables;
};

} // namespace thrumapper
} // namespace gr

#endif
