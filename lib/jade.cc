/* -*- c++ -*- */
/*
 * SPDX-License-Identifier: GPL-3.0-or-later
 */
#include "angles.h"
#include <gnuradio/thrumapper/jade.h>
#include <gnuradio/thrumapper/manifold.h>
#include <gnuradio/thrumapper/projection.h>
#include <Eigen/Eigenvalues>
#include <algorithm>
#include <limits>
#include <cmath>
#include <stdexcept>
#include <string>

namespace gr {
namespace thrumapper {

using cd = std::complex<double>;
using cf = std::complex<float>;
using RowMajorCf = Eigen::Matrix<cf, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;

namespace {
constexpr double two_pi = 2.0 * M_PI;
// Largest pseudo-spectrum reported: the projection residual is floored at 1e-6.
constexpr double min_residual = 1e-6;

double wrap_angle(double a)
{
    a = std::fmod(a, two_pi);
    return a < 0 ? a + two_pi : a;
}

void check_grid(const std::vector<double>& g, const char* name)
{
    if (g.empty())
        throw std::invalid_argument(std::string(name) + ": the grid is empty");
    for (double v : g)
        if (!std::isfinite(v))
            throw std::invalid_argument(std::string(name) + ": grid values must be finite");
}

// The few leading eigenpairs of a Hermitian matrix, without the full eigendecomposition:
// Householder tridiagonalisation (Q kept implicit), eigenvalues by Sturm bisection on the
// real tridiagonal T, eigenvectors by inverse iteration on T and one back-transformation.
// The full QL eigensolver costs about four times as much at the sizes JADE meets (~86).
class leading_eigen
{
public:
    explicit leading_eigen(const Eigen::MatrixXcd& A) : d_tri(A)
    {
        d_n = A.rows();
        d_d = d_tri.diagonal();
        d_e = d_tri.subDiagonal();
        d_lo = d_hi = d_d(0);
        for (int i = 0; i < d_n; i++) {
            const double r = (i > 0 ? std::abs(d_e(i - 1)) : 0.0) + (i < d_n - 1 ? std::abs(d_e(i)) : 0.0);
            d_lo = std::min(d_lo, d_d(i) - r);
            d_hi = std::max(d_hi, d_d(i) + r);
        }
        d_norm = std::max(std::abs(d_lo), std::abs(d_hi));
    }

    int size() const { return d_n; }

    //! The k-th smallest eigenvalue (k = 0 the smallest).
    double kth_smallest(int k) const
    {
        double lo = d_lo, hi = d_hi;
        const double tol = 4 * std::numeric_limits<double>::epsilon() * d_norm + 1e-300;
        for (int it = 0; it < 200 && hi - lo > tol; it++) {
            const double mid = 0.5 * (lo + hi);
            if (count_below(mid) > k)
                hi = mid;
            else
                lo = mid;
        }
        return 0.5 * (lo + hi);
    }

    //! The k-th largest eigenvalue (k = 0 the largest).
    double kth_largest(int k) const { return kth_smallest(d_n - 1 - k); }

    //! Unit eigenvectors for the given eigenvalues (descending), as columns.
    Eigen::MatrixXcd vectors(const std::vector<double>& values) const
    {
        const int n = d_n, K = values.size();
        Eigen::MatrixXd X(n, K);
        for (int k = 0; k < K; k++) {
            // shift just off the eigenvalue so that T - μ stays (barely) invertible
            const double mu = values[k] + 8 * std::numeric_limits<double>::epsilon() * d_norm;
            Eigen::VectorXd x(n);
            for (int i = 0; i < n; i++)
                x(i) = 1.0 + 0.01 * ((i * 7919) % 101); // fixed, not orthogonal to anything
            for (int it = 0; it < 4; it++) {
                solve_shifted(mu, x);
                // keep clustered eigenvalues' vectors apart
                for (int j = 0; j < k; j++)
                    x -= X.col(j).dot(x) * X.col(j);
                x.normalize();
            }
            X.col(k) = x;
        }
        Eigen::MatrixXcd V = X.cast<cd>();
        V.applyOnTheLeft(d_tri.matrixQ());
        return V;
    }

private:
    int count_below(double x) const
    {
        const double tiny = std::numeric_limits<double>::min();
        double q = d_d(0) - x;
        int c = q < 0;
        for (int i = 1; i < d_n; i++) {
            q = d_d(i) - x - d_e(i - 1) * d_e(i - 1) / (q == 0 ? tiny : q);
            c += q < 0;
        }
        return c;
    }

    // Solve (T - μI) x = b in place: tridiagonal LU with partial pivoting (LAPACK dgttrf /
    // dgtts2); a zero pivot is nudged, as inverse iteration wants.
    void solve_shifted(double mu, Eigen::VectorXd& b) const
    {
        const int n = d_n;
        if (n == 1) {
            b(0) /= (d_d(0) - mu == 0 ? 1e-300 : d_d(0) - mu);
            return;
        }
        std::vector<double> dl(d_e.data(), d_e.data() + n - 1), du(dl), du2(std::max(n - 2, 0), 0.0), d(n);
        std::vector<int> ipiv(n - 1);
        for (int i = 0; i < n; i++)
            d[i] = d_d(i) - mu;
        for (int i = 0; i < n - 1; i++) {
            if (std::abs(d[i]) >= std::abs(dl[i])) {
                ipiv[i] = i;
                if (d[i] != 0) {
                    const double fact = dl[i] / d[i];
                    dl[i] = fact;
                    d[i + 1] -= fact * du[i];
                }
            } else {
                ipiv[i] = i + 1;
                const double fact = d[i] / dl[i];
                d[i] = dl[i];
                dl[i] = fact;
                const double temp = du[i];
                du[i] = d[i + 1];
                d[i + 1] = temp - fact * d[i + 1];
                if (i < n - 2) {
                    du2[i] = du[i + 1];
                    du[i + 1] = -fact * du[i + 1];
                }
            }
        }
        const double nudge = std::numeric_limits<double>::epsilon() * d_norm + 1e-300;
        for (int i = 0; i < n; i++)
            if (std::abs(d[i]) < nudge)
                d[i] = d[i] < 0 ? -nudge : nudge;
        for (int i = 0; i < n - 1; i++) {
            const int ip = ipiv[i];
            const double temp = b(2 * i + 1 - ip) - dl[i] * b(ip);
            b(i) = b(ip);
            b(i + 1) = temp;
        }
        b(n - 1) /= d[n - 1];
        b(n - 2) = (b(n - 2) - du[n - 2] * b(n - 1)) / d[n - 2];
        for (int i = n - 3; i >= 0; i--)
            b(i) = (b(i) - du[i] * b(i + 1) - du2[i] * b(i + 2)) / d[i];
    }

    Eigen::Tridiagonalization<Eigen::MatrixXcd> d_tri;
    int d_n;
    Eigen::VectorXd d_d, d_e;
    double d_lo, d_hi, d_norm;
};
} // namespace

jade::jade(radar_description::sptr radar,
           const std::vector<double>& angles_rad,
           const std::vector<double>& delays_s,
           int smoothing_window,
           int max_paths)
    : d_radar(radar),
      d_fixed_order(0),
      d_order_threshold(5.0),
      d_system_delay_s(0.0),
      d_refine(true),
      d_order(0)
{
    if (!radar)
        throw std::invalid_argument("jade: a radar description is required");
    if (!radar->uniform_spacing())
        throw std::invalid_argument(
            "jade: subcarrier smoothing needs uniformly spaced subcarriers");
    d_M = radar->num_rx();
    d_N = radar->num_subcarriers();
    d_df_hz = radar->subcarrier_spacing_hz();
    d_k_rad_m = two_pi * radar->carrier_hz() / speed_of_light_m_s;
    const Eigen::Vector2d c = radar->rx_centre_m();
    d_rx_x = radar->rx_elements_m().col(0).array() - c.x();
    d_rx_y = radar->rx_elements_m().col(1).array() - c.y();
    check_grid(angles_rad, "angles_rad");
    check_grid(delays_s, "delays_s");
    d_angles = angles_rad;
    d_delays = delays_s;
    set_max_paths(max_paths);
    d_L = 0;
    set_smoothing_window(smoothing_window); // builds the grids
}

std::vector<double> jade::full_circle_grid(int count)
{
    if (count < 3)
        throw std::invalid_argument("full_circle_grid: at least 3 angles are needed");
    std::vector<double> g(count);
    for (int i = 0; i < count; i++)
        g[i] = two_pi * i / count;
    return g;
}

std::vector<double> jade::linear_grid(double start, double stop, int count)
{
    if (count < 2)
        throw std::invalid_argument("linear_grid: at least 2 points are needed");
    if (!(stop > start))
        throw std::invalid_argument("linear_grid: stop must be above start");
    std::vector<double> g(count);
    for (int i = 0; i < count; i++)
        g[i] = start + (stop - start) * i / (count - 1);
    return g;
}

void jade::set_angle_grid(const std::vector<double>& angles_rad)
{
    check_grid(angles_rad, "angles_rad");
    d_angles = angles_rad;
    rebuild_grids();
}

void jade::set_delay_grid(const std::vector<double>& delays_s)
{
    check_grid(delays_s, "delays_s");
    d_delays = delays_s;
    rebuild_grids();
}

void jade::set_smoothing_window(int subcarriers)
{
    // N/3 balances the aperture of the window (M·L) against that of the snapshots
    // (N-L+1): with N/2 the snapshots resolve crowded delays poorly (docs/estimator.md).
    const int L = subcarriers == 0 ? (d_N + 1) / 3 : subcarriers;
    if (L < 2 || L > d_N - 1)
        throw std::invalid_argument("smoothing_window: expected 2 to N-1 = " +
                                    std::to_string(d_N - 1) + " subcarriers (0 for N/3), got " +
                                    std::to_string(subcarriers));
    d_L = L;
    rebuild_grids();
}

void jade::set_max_paths(int max_paths)
{
    if (max_paths < 1 || max_paths > 64)
        throw std::invalid_argument("max_paths: expected 1 to 64, got " + std::to_string(max_paths));
    d_max_paths = max_paths;
}

void jade::set_model_order(int order)
{
    if (order < 0 || order > 64)
        throw std::invalid_argument("model_order: expected 0 (automatic) to 64, got " +
                                    std::to_string(order));
    d_fixed_order = order;
}

void jade::set_order_threshold(double factor)
{
    if (!(factor > 1.0) || !std::isfinite(factor))
        throw std::invalid_argument("order_threshold: expected a factor above 1");
    d_order_threshold = factor;
}

void jade::set_system_delay(double system_delay_s)
{
    if (!std::isfinite(system_delay_s))
        throw std::invalid_argument("system_delay_s must be finite");
    d_system_delay_s = system_delay_s;
    rebuild_grids();
}

void jade::set_refine(bool refine) { d_refine = refine; }

void jade::rebuild_grids()
{
    const int A = d_angles.size(), D = d_delays.size();
    d_Ah.resize(A, d_M);
    for (int a = 0; a < A; a++) {
        const double ux = std::cos(d_angles[a]), uy = std::sin(d_angles[a]);
        for (int m = 0; m < d_M; m++)
            d_Ah(a, m) = std::polar(1.0f, float(-d_k_rad_m * (d_rx_x(m) * ux + d_rx_y(m) * uy)));
    }
    // The smoothing window's own first subcarrier is the phase reference of g: a path's
    // scalar phase does not change the subspace.
    d_Gc.resize(d_L, D);
    for (int d = 0; d < D; d++) {
        const double tau = d_delays[d] + d_system_delay_s;
        for (int l = 0; l < d_L; l++) {
            // reduce the phase in double before the float conversion
            const double ph = std::fmod(two_pi * l * d_df_hz * tau, two_pi);
            d_Gc(l, d) = std::polar(1.0f, float(ph));
        }
    }
    // Is the angle grid a uniform full circle? Then peaks wrap around.
    d_full_circle = false;
    if (A >= 3) {
        const double step = d_angles[1] - d_angles[0];
        d_full_circle = step > 0 && std::abs(d_angles[A - 1] - d_angles[0] + step - two_pi) < 1e-6 * two_pi;
    }
    d_spectrum_db.setZero(A, D);
    d_fit.setZero(A, D);
}

void jade::check_frames(const Eigen::MatrixXcd& frames) const
{
    if (frames.cols() != d_N)
        throw std::invalid_argument("jade: expected frames of N = " + std::to_string(d_N) +
                                    " subcarriers, got " + std::to_string(frames.cols()));
    if (frames.rows() < d_M || frames.rows() % d_M != 0)
        throw std::invalid_argument("jade: expected a whole number of frames of M = " +
                                    std::to_string(d_M) + " RX elements, got " +
                                    std::to_string(frames.rows()) + " rows");
    const int F = frames.rows() / d_M;
    for (int f = 0; f < F; f++) {
        const auto block = frames.middleRows(f * d_M, d_M);
        if (!block.allFinite())
            throw std::invalid_argument("jade: frame " + std::to_string(f) +
                                        " holds NaN or Inf values");
        if (block.squaredNorm() == 0.0)
            throw std::invalid_argument("jade: frame " + std::to_string(f) +
                                        " is all zeros (no signal)");
    }
}

Eigen::MatrixXcd jade::smooth(const Eigen::MatrixXcd& frames, int num_rx, int window)
{
    const int N = frames.cols();
    const int F = frames.rows() / num_rx;
    const int S = N - window + 1;
    if (window < 1 || S < 1)
        throw std::invalid_argument("smooth: window must be 1 to N");
    Eigen::MatrixXcd Y(num_rx * window, F * S);
    for (int f = 0; f < F; f++)
        for (int m = 0; m < num_rx; m++)
            for (int i = 0; i < S; i++)
                Y.block(m * window, f * S + i, window, 1) =
                    frames.row(f * num_rx + m).segment(i, window).transpose();
    return Y;
}

void jade::compute_subspace(const Eigen::MatrixXcd& frames)
{
    const int M = d_M, N = d_N, L = d_L;
    const int F = frames.rows() / M;
    const int S = N - L + 1;
    const int FS = F * S, ML = M * L;
    // the Gram Yᴴ Y, or the covariance Y Yᴴ, whichever is smaller (buffers kept between calls)
    Eigen::MatrixXcd& A = d_gram;
    if (FS <= ML) {
        // Gram route: G = Yᴴ Y (FS × FS) from X = H_fᴴ H_f' (N × N) by sums along its
        // diagonals, Y never formed. G(i,j) = Σ_l X(i+l, j+l).
        A.resize(FS, FS);
        Eigen::MatrixXcd& X = d_cross;
        Eigen::MatrixXcd& P = d_prefix;
        X.resize(N, N);
        P.resize(N, N);
        for (int f = 0; f < F; f++)
            for (int g = f; g < F; g++) {
                X.noalias() = frames.middleRows(f * M, M).adjoint() * frames.middleRows(g * M, M);
                for (int b = 0; b < N; b++)
                    for (int a = 0; a < N; a++)
                        P(a, b) = X(a, b) + ((a > 0 && b > 0) ? P(a - 1, b - 1) : cd(0));
                for (int j = 0; j < S; j++)
                    for (int i = 0; i < S; i++) {
                        cd v = P(i + L - 1, j + L - 1);
                        if (i > 0 && j > 0)
                            v -= P(i - 1, j - 1);
                        A(f * S + i, g * S + j) = v;
                        if (g != f)
                            A(g * S + j, f * S + i) = std::conj(v);
                    }
            }
    } else {
        const Eigen::MatrixXcd Y = smooth(frames, M, L);
        A.setZero(ML, ML);
        A.selfadjointView<Eigen::Lower>().rankUpdate(Y);
        A = A.selfadjointView<Eigen::Lower>();
    }
    const leading_eigen eig(A);
    const int dim = eig.size();

    // Model order: eigenvalues above threshold × the median eigenvalue (the noise level;
    // most eigenvalues are noise when paths are few), and above the numerical floor of
    // noiseless data. Only the eigenvalues the rule looks at are computed.
    const int max_order = std::max(1, std::min(dim / 2, 32));
    d_noise_eigenvalue = std::max(eig.kth_smallest(dim / 2), 0.0);
    std::vector<double> leading;
    int order;
    if (d_fixed_order > 0) {
        order = std::min(d_fixed_order, dim - 1);
        for (int k = 0; k <= order && k < dim; k++)
            leading.push_back(std::max(eig.kth_largest(k), 0.0));
    } else {
        leading.push_back(std::max(eig.kth_largest(0), 0.0));
        const double level = std::max(d_order_threshold * d_noise_eigenvalue, 1e-10 * leading[0]);
        order = 0;
        while (order < max_order && leading[order] > level) {
            order++;
            if (order < dim)
                leading.push_back(std::max(eig.kth_largest(order), 0.0));
            else
                break;
        }
    }
    d_order = order;
    d_eigenvalues = Eigen::Map<const Eigen::VectorXd>(leading.data(), leading.size());
    const std::vector<double> signal_values(leading.begin(), leading.begin() + order);
    const Eigen::MatrixXcd V = eig.vectors(signal_values);

    d_Es.resize(ML, order);
    if (FS <= ML) {
        // E_s = Y v / sqrt(λ): a correlation of each element's subcarriers with v.
        for (int k = 0; k < order; k++) {
            const double scale = 1.0 / std::sqrt(std::max(d_eigenvalues(k), 1e-300));
            for (int m = 0; m < M; m++)
                for (int l = 0; l < L; l++) {
                    cd acc(0);
                    for (int f = 0; f < F; f++)
                        acc += (frames.row(f * M + m).segment(l, S).transpose().array() *
                                V.col(k).segment(f * S, S).array())
                                   .sum();
                    d_Es(m * L + l, k) = acc * scale;
                }
        }
        // guard the orthonormality the SVD identity promises against round-off
        if (order > 0) {
            Eigen::HouseholderQR<Eigen::MatrixXcd> qr(d_Es);
            d_Es = qr.householderQ() * Eigen::MatrixXcd::Identity(ML, order);
        }
    } else {
        d_Es = V;
    }
}

void jade::compute_spectrum()
{
    const int A = d_angles.size(), D = d_delays.size();
    const int order = d_order, M = d_M;
    if (order == 0) {
        d_fit.setZero(A, D);
        d_spectrum_db.setZero(A, D);
        return;
    }
    // Delay transform: per signal vector, its M×L reshape times the L×D delay manifold,
    // kept as split real/imaginary float rows so that the angle stage vectorises over delays.
    d_Esf = d_Es.cast<cf>();
    d_Dall.resize(M, D);
    d_Dre.resize(size_t(order) * M * D);
    d_Dim.resize(size_t(order) * M * D);
    for (int k = 0; k < order; k++) {
        Eigen::Map<const RowMajorCf> B(d_Esf.col(k).data(), M, d_L);
        d_Dall.noalias() = B * d_Gc;
        for (int m = 0; m < M; m++)
            for (int d = 0; d < D; d++) {
                d_Dre[(size_t(k) * M + m) * D + d] = d_Dall(m, d).real();
                d_Dim[(size_t(k) * M + m) * D + d] = d_Dall(m, d).imag();
            }
    }
    // Angle stage, fused with |·|² and the sum over signal vectors: for every angle,
    // z_k(d) = Σ_m conj(a_m(θ)) D_k(m, d), fit(θ, d) = Σ_k |z_k(d)|² / (M·L). The M·order
    // rows of D stay in cache; nothing of size angles × delays × order is stored.
    d_zr.resize(D);
    d_zi.resize(D);
    d_acc.resize(D);
    const float norm = 1.0f / float(M * d_L);
    float* zr = d_zr.data();
    float* zi = d_zi.data();
    float* acc = d_acc.data();
    for (int a = 0; a < A; a++) {
        std::fill(acc, acc + D, 0.0f);
        for (int k = 0; k < order; k++) {
            std::fill(zr, zr + D, 0.0f);
            std::fill(zi, zi + D, 0.0f);
            for (int m = 0; m < M; m++) {
                const float ar = d_Ah(a, m).real(), ai = d_Ah(a, m).imag();
                const float* dr = &d_Dre[(size_t(k) * M + m) * D];
                const float* di = &d_Dim[(size_t(k) * M + m) * D];
                for (int d = 0; d < D; d++) {
                    zr[d] += ar * dr[d] - ai * di[d];
                    zi[d] += ar * di[d] + ai * dr[d];
                }
            }
            for (int d = 0; d < D; d++)
                acc[d] += zr[d] * zr[d] + zi[d] * zi[d];
        }
        for (int d = 0; d < D; d++)
            d_fit(a, d) = acc[d] * norm;
    }
    // -10·log10 as a natural log (Eigen vectorises log, not log10)
    const float db_per_neper = float(-10.0 / std::log(10.0));
    d_spectrum_db = (db_per_neper * (1.0f - d_fit.array()).max(float(min_residual)).log()).matrix();
}

std::vector<std::pair<int, int>> jade::grid_peaks(int wanted) const
{
    const int A = d_fit.rows(), D = d_fit.cols();
    std::vector<std::pair<float, std::pair<int, int>>> cand;
    // A peak is a cell no lower than its 8 neighbours. The cheap tests come first: most cells
    // are below a floor (no path has so small a projection), or below a delay neighbour.
    constexpr float floor = 0.05f;
    for (int a = 0; a < A; a++)
        for (int d = 0; d < D; d++) {
            const float v = d_fit(a, d);
            if (v < floor || (d > 0 && v < d_fit(a, d - 1)) || (d < D - 1 && v < d_fit(a, d + 1)))
                continue;
            bool peak = true;
            for (int da = -1; da <= 1 && peak; da++)
                for (int dd = -1; dd <= 1; dd++) {
                    if (da == 0 && dd == 0)
                        continue;
                    int aa = a + da;
                    const int nd = d + dd;
                    if (nd < 0 || nd >= D)
                        continue;
                    if (aa < 0 || aa >= A) {
                        if (!d_full_circle)
                            continue;
                        aa = (aa + A) % A;
                    }
                    const float w = d_fit(aa, nd);
                    // ties go to the first in scan order, so a plateau yields one peak
                    if (w > v || (w == v && (aa < a || (aa == a && nd < d)))) {
                        peak = false;
                        break;
                    }
                }
            if (peak)
                cand.push_back({ v, { a, d } });
        }
    std::sort(cand.begin(), cand.end(), [](const auto& x, const auto& y) { return x.first > y.first; });
    if (static_cast<int>(cand.size()) > wanted)
        cand.resize(wanted);
    std::vector<std::pair<int, int>> out;
    for (const auto& c : cand)
        out.push_back(c.second);
    return out;
}

double jade::fit_at(double aoa_rad, double delay_total_s) const
{
    const int M = d_M, L = d_L;
    Eigen::VectorXcd a(M), g(L);
    for (int m = 0; m < M; m++)
        a(m) = std::polar(1.0, d_k_rad_m * (d_rx_x(m) * std::cos(aoa_rad) + d_rx_y(m) * std::sin(aoa_rad)));
    for (int l = 0; l < L; l++)
        g(l) = std::polar(1.0, -two_pi * l * d_df_hz * delay_total_s);
    double s = 0;
    for (int k = 0; k < d_Es.cols(); k++) {
        Eigen::Map<const Eigen::Matrix<cd, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>> B(
            d_Es.col(k).data(), M, L);
        const cd z = a.transpose() * (B.conjugate() * g);
        s += std::norm(z);
    }
    return s / (M * L);
}

double jade::subspace_fit(double aoa_rad, double delay_s) const
{
    return fit_at(aoa_rad, delay_s + d_system_delay_s);
}

// Newton ascent of the projection fit f(θ, τ) with analytic derivatives of the separable
// manifold; τ is scaled to nanoseconds so both variables are of order one.
bool jade::refine_peak(double& aoa_rad, double& delay_total_s) const
{
    const int M = d_M, L = d_L, K = d_Es.cols();
    const double ns = 1e-9;
    std::vector<Eigen::Matrix<cd, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>> W(K);
    for (int k = 0; k < K; k++)
        W[k] = Eigen::Map<const Eigen::Matrix<cd, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>>(
                   d_Es.col(k).data(), M, L)
                   .conjugate();
    Eigen::VectorXd lw(L);
    for (int l = 0; l < L; l++)
        lw(l) = -two_pi * l * d_df_hz * ns; // d(phase)/d(τ in ns)

    auto evaluate = [&](double th, double s, Eigen::Vector2d* grad, Eigen::Matrix2d* hess) {
        Eigen::VectorXcd a(M), a1(M), a2(M), g(L), g1(L), g2(L);
        const double c = std::cos(th), sn = std::sin(th);
        for (int m = 0; m < M; m++) {
            const double q = -d_rx_x(m) * sn + d_rx_y(m) * c;  // d(proj)/dθ
            const double q1 = -d_rx_x(m) * c - d_rx_y(m) * sn; // d²(proj)/dθ²
            a(m) = std::polar(1.0, d_k_rad_m * (d_rx_x(m) * c + d_rx_y(m) * sn));
            const cd jk(0, d_k_rad_m);
            a1(m) = jk * q * a(m);
            a2(m) = (jk * q1 + (jk * q) * (jk * q)) * a(m);
        }
        for (int l = 0; l < L; l++) {
            g(l) = std::polar(1.0, lw(l) * s);
            g1(l) = cd(0, lw(l)) * g(l);
            g2(l) = -lw(l) * lw(l) * g(l);
        }
        double f = 0;
        Eigen::Vector2d gr = Eigen::Vector2d::Zero();
        Eigen::Matrix2d h = Eigen::Matrix2d::Zero();
        for (int k = 0; k < K; k++) {
            const Eigen::VectorXcd t = W[k] * g;
            const cd z = a.transpose() * t;
            f += std::norm(z);
            if (grad) {
                const Eigen::VectorXcd t1 = W[k] * g1;
                const Eigen::VectorXcd t2 = W[k] * g2;
                const cd zt = a1.transpose() * t, zs = a.transpose() * t1;
                const cd ztt = a2.transpose() * t, zss = a.transpose() * t2, zts = a1.transpose() * t1;
                gr(0) += 2 * std::real(std::conj(z) * zt);
                gr(1) += 2 * std::real(std::conj(z) * zs);
                h(0, 0) += 2 * std::real(std::norm(zt) + std::conj(z) * ztt);
                h(1, 1) += 2 * std::real(std::norm(zs) + std::conj(z) * zss);
                h(0, 1) += 2 * std::real(std::conj(zt) * zs + std::conj(z) * zts);
            }
        }
        const double norm = 1.0 / (M * L);
        if (grad) {
            *grad = gr * norm;
            h(1, 0) = h(0, 1);
            *hess = h * norm;
        }
        return f * norm;
    };

    // Moves are bounded to a few grid cells: a refined peak that runs away is not this peak.
    const double th0 = aoa_rad, s0 = delay_total_s / ns;
    double th = th0, s = s0;
    const double max_dth = 0.1, max_ds = 2.0 / (d_df_hz * d_L) / ns;
    Eigen::Vector2d grad;
    Eigen::Matrix2d hess;
    double f = evaluate(th, s, &grad, &hess);
    for (int it = 0; it < 50; it++) {
        Eigen::Vector2d step;
        Eigen::SelfAdjointEigenSolver<Eigen::Matrix2d> es(hess);
        if (es.eigenvalues().maxCoeff() < 0) {
            step = -hess.ldlt().solve(grad);
        } else {
            // not concave here: a gradient step scaled by the largest curvature
            const double curv = std::max(es.eigenvalues().cwiseAbs().maxCoeff(), 1e-12);
            step = grad / curv;
        }
        double t = 1.0;
        bool accepted = false;
        Eigen::Vector2d g2;
        Eigen::Matrix2d h2;
        for (int ls = 0; ls < 30; ls++) {
            const double th2 = th + t * step(0), s2 = s + t * step(1);
            const double f2 = evaluate(th2, s2, &g2, &h2);
            if (f2 >= f - 1e-15) {
                th = th2;
                s = s2;
                f = f2;
                grad = g2;
                hess = h2;
                accepted = true;
                break;
            }
            t *= 0.5;
        }
        if (!accepted || (std::abs(t * step(0)) < 1e-12 && std::abs(t * step(1)) < 1e-9))
            break;
        if (std::abs(th - th0) > max_dth || std::abs(s - s0) > max_ds)
            return false;
    }
    aoa_rad = wrap_angle(th);
    delay_total_s = s * ns;
    return true;
}

void jade::fit_amplitudes(const Eigen::MatrixXcd& frames, std::vector<jade_path>& paths) const
{
    if (paths.empty())
        return;
    const int M = d_M, N = d_N, F = frames.rows() / M;
    // Keep, in the given order, only paths the data can tell apart: a manifold vector within
    // 0.995 correlation of the span of those kept is the same echo found twice (a least-squares
    // fit of both would give them huge opposite gains).
    std::vector<jade_path> kept;
    std::vector<Eigen::VectorXcd> basis, columns;
    for (const auto& p : paths) {
        Eigen::VectorXcd u = space_time_manifold(*d_radar, p.aoa_rad, p.delay_s + d_system_delay_s);
        Eigen::VectorXcd r = u;
        for (const auto& q : basis)
            r -= q * q.dot(r);
        if (r.squaredNorm() < 1e-2 * u.squaredNorm())
            continue;
        basis.push_back(r.normalized());
        columns.push_back(u);
        kept.push_back(p);
    }
    paths = kept;
    const int P = paths.size();
    Eigen::MatrixXcd U(M * N, P);
    for (int p = 0; p < P; p++)
        U.col(p) = columns[p];
    const Eigen::MatrixXcd UhU = U.adjoint() * U;
    const Eigen::LDLT<Eigen::MatrixXcd> ldlt(UhU);
    Eigen::VectorXd power = Eigen::VectorXd::Zero(P);
    Eigen::VectorXcd h(M * N);
    for (int f = 0; f < F; f++) {
        for (int m = 0; m < M; m++)
            h.segment(m * N, N) = frames.row(f * M + m).transpose();
        const Eigen::VectorXcd gamma = ldlt.solve(U.adjoint() * h);
        power += gamma.cwiseAbs2();
        if (f == 0)
            for (int p = 0; p < P; p++)
                paths[p].amplitude = gamma(p);
    }
    for (int p = 0; p < P; p++)
        paths[p].power = power(p) / F;
}

std::vector<jade_path> jade::estimate(const std::complex<float>* frames, int num_frames)
{
    if (frames == nullptr || num_frames < 1)
        throw std::invalid_argument("jade: no frames");
    Eigen::Map<const Eigen::Matrix<cf, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>> map(
        frames, num_frames * d_M, d_N);
    return estimate_matrix(map.cast<cd>());
}

std::vector<jade_path> jade::estimate_once(const Eigen::MatrixXcd& frames, int max_paths)
{
    compute_subspace(frames);
    compute_spectrum();
    std::vector<jade_path> paths;
    const int wanted = std::min(d_order, max_paths);
    if (wanted == 0)
        return paths;
    // A few spare grid peaks: refinement may merge two cells of one peak.
    const auto peaks = grid_peaks(d_order + 4);
    const double merge_angle = 1e-3, merge_delay = 1e-12;
    for (const auto& pk : peaks) {
        double th = d_angles[pk.first];
        double tau = d_delays[pk.second] + d_system_delay_s;
        if (d_refine && !refine_peak(th, tau)) {
            th = d_angles[pk.first];
            tau = d_delays[pk.second] + d_system_delay_s;
        }
        th = wrap_angle(th);
        bool duplicate = false;
        for (const auto& q : paths) {
            if (angle_distance(q.aoa_rad, th) < merge_angle &&
                std::abs(q.delay_s + d_system_delay_s - tau) < merge_delay)
                duplicate = true;
        }
        if (duplicate)
            continue;
        jade_path p;
        p.aoa_rad = th;
        p.delay_s = tau - d_system_delay_s;
        p.spectrum_db = -10.0 * std::log10(std::max(1.0 - fit_at(th, tau), min_residual));
        paths.push_back(p);
    }
    // The pseudo-spectrum's height is not power: fit the gains of every peak the model order
    // allows, together, and keep the strongest.
    std::sort(paths.begin(), paths.end(), [](const jade_path& x, const jade_path& y) {
        return x.spectrum_db > y.spectrum_db;
    });
    if (static_cast<int>(paths.size()) > d_order)
        paths.resize(d_order);
    fit_amplitudes(frames, paths);
    std::stable_sort(paths.begin(), paths.end(), [](const jade_path& x, const jade_path& y) {
        return x.power > y.power;
    });
    if (static_cast<int>(paths.size()) > wanted)
        paths.resize(wanted);
    return paths;
}

std::vector<jade_path> jade::estimate_matrix(const Eigen::MatrixXcd& frames)
{
    check_frames(frames);
    if (d_stages <= 1)
        return estimate_once(frames, d_max_paths);

    // Successive cancellation (paper §2.3.2, §4.3): estimate; cancel every return found by
    // projection (path_projector, on the whole frames); estimate again on what is left, where
    // weaker returns are no longer outranked. Each stage reports up to max_paths paths. Stops
    // after the last stage, or when what is left is noise (the model-order rule finds no
    // signal: on noise alone it fires in fewer than 1 frame in 1000), or when a stage finds
    // only paths next to those already cancelled (the residue of an echo estimated a little
    // off, or of model mismatch, not new echoes).
    if (!d_projector)
        d_projector = std::make_unique<path_projector>(d_radar);
    d_projector->set_system_delay(d_system_delay_s);
    std::vector<double> aoas, delays;
    d_projector->set_paths(aoas, delays);
    std::vector<jade_path> found;
    Eigen::MatrixXcd work = frames;
    Eigen::Matrix<float, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor> first_spectrum;
    Eigen::VectorXd first_eigenvalues;
    int first_order = 0;
    for (int stage = 0; stage < d_stages; stage++) {
        std::vector<jade_path> paths = estimate_once(work, d_max_paths);
        if (stage == 0) {
            first_spectrum = d_spectrum_db;
            first_eigenvalues = d_eigenvalues;
            first_order = d_order;
        }
        int added = 0;
        for (auto& p : paths) {
            // within a quarter of a resolution cell (5°, 1 ns) of an echo already cancelled:
            // what its imperfect cancellation left, not a new echo
            bool again = false;
            for (const auto& q : found) {
                const double a = angle_distance(q.aoa_rad, p.aoa_rad) / (5 * M_PI / 180);
                const double d = (q.delay_s - p.delay_s) / 1e-9;
                if (a * a + d * d < 1)
                    again = true;
            }
            if (again)
                continue;
            p.stage = stage;
            found.push_back(p);
            aoas.push_back(p.aoa_rad);
            delays.push_back(p.delay_s);
            added++;
        }
        if (added == 0 || stage == d_stages - 1)
            break;
        d_projector->set_paths(aoas, delays);
        work = d_projector->apply_matrix(frames);
    }
    // The gains of all the paths found, fitted together on the original frames; the
    // spectrum and eigenvalues reported are those of the first stage (the raw data).
    fit_amplitudes(frames, found);
    std::stable_sort(found.begin(), found.end(), [](const jade_path& x, const jade_path& y) {
        return x.power > y.power;
    });
    d_spectrum_db = first_spectrum;
    d_eigenvalues = first_eigenvalues;
    d_order = first_order;
    return found;
}

void jade::set_stages(int stages)
{
    if (stages < 1 || stages > 16)
        throw std::invalid_argument("stages: expected 1 to 16, got " + std::to_string(stages));
    d_stages = stages;
}

} // namespace thrumapper
} // namespace gr
