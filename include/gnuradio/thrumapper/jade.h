/* -*- c++ -*- */
/*
 * SPDX-License-Identifier: GPL-3.0-or-later
 */
#ifndef INCLUDED_THRUMAPPER_JADE_H
#define INCLUDED_THRUMAPPER_JADE_H

#include <gnuradio/thrumapper/api.h>
#include <gnuradio/thrumapper/projection.h>
#include <gnuradio/thrumapper/radar_description.h>
#include <Eigen/Dense>
#include <complex>
#include <memory>
#include <vector>

namespace gr {
namespace thrumapper {

//! One propagation path found by JADE.
struct THRUMAPPER_API jade_path {
    double aoa_rad = 0;      //!< angle of arrival at the RX centre, CCW from robot +x, [0, 2π)
    double delay_s = 0;      //!< TX-centre to RX-centre propagation delay, system delay removed
    double power = 0;        //!< |complex gain|², mean over the frames (CSI units squared)
    std::complex<double> amplitude{ 0, 0 }; //!< complex gain in the first frame
    double spectrum_db = 0;  //!< MUSIC pseudo-spectrum at the refined peak, dB
    int stage = 0;           //!< successive-cancellation stage that found it (0: the first)
};

/*!
 * \brief JADE: joint angle and delay estimation (paper §2.2, eq. 5–8), the fast way.
 * \ingroup thrumapper
 *
 * Input: F frames of CSI, each M×N complex, element-major (entry m·N + n: RX element m,
 * subcarrier n). The frames are smoothed over subcarriers (Hankel window L, eq. 6–7), their
 * snapshots stacked; the signal subspace comes from the eigenvectors of the small Gram matrix
 * of the smoothed data (a thin SVD), never from the large M·L×M·L covariance when the Gram is
 * smaller; the model order from the eigenvalues; the MUSIC spectrum (eq. 8) on the grid is
 * evaluated separably (a delay transform then one complex GEMM for all angles); grid peaks
 * are refined by Newton iterations on the exact projection cost.
 *
 * Not thread safe: one thread at a time (the block holds a lock).
 */
class THRUMAPPER_API jade
{
public:
    /*!
     * \param radar the radar description (RX geometry, carrier, uniform subcarriers).
     * \param angles_rad the angle grid (any values, radians).
     * \param delays_s the delay grid (any values, seconds, system delay removed).
     * \param smoothing_window L, subcarriers per smoothing window; 0 means N/3.
     * \param max_paths the most paths reported per estimate.
     */
    jade(radar_description::sptr radar,
         const std::vector<double>& angles_rad,
         const std::vector<double>& delays_s,
         int smoothing_window = 0,
         int max_paths = 4);

    //! The angle grid as n uniformly spaced values over [0, 2π).
    static std::vector<double> full_circle_grid(int count);
    //! n uniformly spaced values from start to stop inclusive.
    static std::vector<double> linear_grid(double start, double stop, int count);

    void set_angle_grid(const std::vector<double>& angles_rad);
    void set_delay_grid(const std::vector<double>& delays_s);
    void set_smoothing_window(int subcarriers);
    void set_max_paths(int max_paths);
    //! Fix the model order (number of signal eigenvectors); 0 restores the automatic rule.
    void set_model_order(int order);
    /*!
     * \brief Threshold of the automatic model order: an eigenvalue counts as signal when it
     * exceeds this factor times the median eigenvalue (the noise level). Default 5: with the
     * default window N/3, on noise alone the largest eigenvalue exceeds 3.7 × the median in
     * fewer than 1 frame in 1000 (N = 64 to 256, measured; never above 4.2 in 3000 frames).
     */
    void set_order_threshold(double factor);
    //! System delay τ_sys removed from every delay (FORMATS.md); default 0.
    void set_system_delay(double system_delay_s);
    void set_refine(bool refine);
    /*!
     * \brief Successive cancellation: 1 (the default) estimates once; S > 1 estimates, cancels
     * the returns found by projection (path_projector), estimates again on what is left, up to
     * S stages or until the residual is noise. Each stage reports up to max_paths paths; each
     * path records its stage.
     */
    void set_stages(int stages);
    int stages() const { return d_stages; }

    const std::vector<double>& angle_grid() const { return d_angles; }
    const std::vector<double>& delay_grid() const { return d_delays; }
    int smoothing_window() const { return d_L; }
    int max_paths() const { return d_max_paths; }
    double system_delay() const { return d_system_delay_s; }
    double order_threshold() const { return d_order_threshold; }
    radar_description::sptr radar() const { return d_radar; }

    /*!
     * \brief Estimate the paths in num_frames frames of M·N complex values each.
     * Throws std::invalid_argument on NaN/Inf or an all-zero frame, naming the frame.
     */
    std::vector<jade_path> estimate(const std::complex<float>* frames, int num_frames);
    //! The same for frames as one (num_frames·M) × N matrix (rows: frame-major, element).
    std::vector<jade_path> estimate_matrix(const Eigen::MatrixXcd& frames);

    //! Spectrum of the last estimate, dB, angles × delays (row-major in memory).
    const Eigen::Matrix<float, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>& spectrum_db() const
    {
        return d_spectrum_db;
    }
    /*!
     * \brief The leading eigenvalues of the smoothed data's Gram (or covariance) in the last
     * estimate, descending: the signal eigenvalues and the first below the order threshold.
     */
    const Eigen::VectorXd& eigenvalues() const { return d_eigenvalues; }
    //! The median eigenvalue of the last estimate: the noise level of the order rule.
    double noise_eigenvalue() const { return d_noise_eigenvalue; }
    //! Model order used by the last estimate.
    int model_order() const { return d_order; }
    //! Orthonormal signal subspace of the last estimate, (M·L) × order.
    const Eigen::MatrixXcd& signal_subspace() const { return d_Es; }
    /*!
     * \brief Normalised projection ||E_sᴴ u(θ, τ)||² / ||u||² of the smoothed manifold on the
     * last signal subspace: 1 at a noiseless path; the spectrum is -10·log10(1 - this).
     */
    double subspace_fit(double aoa_rad, double delay_s) const;

    /*!
     * \brief Smoothed data (eq. 6–7): (M·L) × (F·(N-L+1)); row m·L + l, column f·S + i holds
     * frame f, element m, subcarrier i + l.
     */
    static Eigen::MatrixXcd smooth(const Eigen::MatrixXcd& frames, int num_rx, int window);

private:
    void rebuild_grids();
    void check_frames(const Eigen::MatrixXcd& frames) const;
    void compute_subspace(const Eigen::MatrixXcd& frames);
    void compute_spectrum();
    std::vector<std::pair<int, int>> grid_peaks(int wanted) const;
    std::vector<jade_path> estimate_once(const Eigen::MatrixXcd& frames, int max_paths);
    bool refine_peak(double& aoa_rad, double& delay_total_s) const;
    void fit_amplitudes(const Eigen::MatrixXcd& frames, std::vector<jade_path>& paths) const;
    double fit_at(double aoa_rad, double delay_total_s) const;

    radar_description::sptr d_radar;
    int d_M, d_N, d_L;
    int d_max_paths;
    int d_fixed_order;
    double d_order_threshold;
    double d_system_delay_s;
    bool d_refine;
    int d_stages = 1;
    std::unique_ptr<path_projector> d_projector;
    double d_df_hz;
    double d_k_rad_m;
    Eigen::VectorXd d_rx_x, d_rx_y; // RX elements relative to the RX centre
    std::vector<double> d_angles, d_delays;
    bool d_full_circle;

    // grid manifolds, single precision for the spectrum GEMMs
    Eigen::MatrixXcf d_Ah;   // angles × M: conj(a_m(θ))
    Eigen::MatrixXcf d_Gc;   // L × D: conj(g_l(τ)), τ including the system delay
    // per-estimate state, kept to avoid reallocation
    Eigen::MatrixXcd d_gram, d_cross, d_prefix;
    Eigen::MatrixXcd d_Es;   // (M·L) × order
    Eigen::MatrixXcf d_Esf;
    Eigen::MatrixXcf d_Dall; // M × D, one signal vector's delay transform
    std::vector<float> d_Dre, d_Dim; // order × M × D, split real and imaginary parts
    std::vector<float> d_zr, d_zi, d_acc;
    Eigen::VectorXd d_eigenvalues;
    double d_noise_eigenvalue = 0;
    int d_order;
    Eigen::Matrix<float, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor> d_spectrum_db;
    Eigen::Matrix<float, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor> d_fit; // A × D projection
};

} // namespace thrumapper
} // namespace gr

#endif
