/* -*- c++ -*- */
/*
 * SPDX-License-Identifier: GPL-3.0-or-later
 */
#include <gnuradio/thrumapper/slab_echo.h>
#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <string>

namespace gr {
namespace thrumapper {

namespace {
const double speed_of_light_m_s = 299792458.0;
// The phase ramp's block of subcarriers (phase_ramp).
const int exact_every = 16;
} // namespace

slab_echo::slab_echo(const Eigen::MatrixXd& tx_elements_m,
                     const Eigen::MatrixXd& rx_elements_m,
                     double carrier_hz,
                     const std::vector<double>& subcarrier_offsets_hz)
    : d_dk(0.0), d_uniform(false)
{
    if (tx_elements_m.cols() != 2 || tx_elements_m.rows() < 1)
        throw std::invalid_argument(
            "slab_echo: tx_elements_m must be (K, 2), K >= 1, got (" +
            std::to_string(tx_elements_m.rows()) + ", " +
            std::to_string(tx_elements_m.cols()) + ")");
    if (rx_elements_m.cols() != 2 || rx_elements_m.rows() < 1)
        throw std::invalid_argument(
            "slab_echo: rx_elements_m must be (M, 2), M >= 1, got (" +
            std::to_string(rx_elements_m.rows()) + ", " +
            std::to_string(rx_elements_m.cols()) + ")");
    if (subcarrier_offsets_hz.empty())
        throw std::invalid_argument("slab_echo: no subcarriers");
    if (!std::isfinite(carrier_hz) || carrier_hz <= 0.0)
        throw std::invalid_argument("slab_echo: carrier_hz must be positive, got " +
                                    std::to_string(carrier_hz));
    if (!tx_elements_m.allFinite() || !rx_elements_m.allFinite())
        throw std::invalid_argument("slab_echo: element positions must be finite");
    d_tx = tx_elements_m;
    d_rx = rx_elements_m;
    const size_t n = subcarrier_offsets_hz.size();
    d_k.resize(n);
    d_lambda.resize(n);
    for (size_t i = 0; i < n; i++) {
        const double f_hz = carrier_hz + subcarrier_offsets_hz[i];
        if (!std::isfinite(f_hz) || f_hz <= 0.0)
            throw std::invalid_argument("slab_echo: subcarrier " + std::to_string(i) +
                                        " is not a positive frequency");
        d_k[i] = 2.0 * M_PI * f_hz / speed_of_light_m_s;
        d_lambda[i] = speed_of_light_m_s / f_hz;
    }
    if (n >= 2) {
        const double step_hz = subcarrier_offsets_hz[1] - subcarrier_offsets_hz[0];
        d_uniform = step_hz != 0.0;
        for (size_t i = 2; i < n && d_uniform; i++) {
            const double expected =
                subcarrier_offsets_hz[0] + step_hz * static_cast<double>(i);
            d_uniform =
                std::abs(subcarrier_offsets_hz[i] - expected) <= 1e-9 * std::abs(step_hz);
        }
        d_dk = 2.0 * M_PI * step_hz / speed_of_light_m_s;
    }
}

int slab_echo::add_table(const table_type& table)
{
    if (table.rows() < 2 || table.cols() != static_cast<Eigen::Index>(d_k.size()))
        throw std::invalid_argument("slab_echo: a coefficient table must be (A >= 2, " +
                                    std::to_string(d_k.size()) + "), got (" +
                                    std::to_string(table.rows()) + ", " +
                                    std::to_string(table.cols()) + ")");
    if (!table.allFinite())
        throw std::invalid_argument(
            "slab_echo: a coefficient table holds NaN or infinity");
    d_tables.push_back(table);
    return static_cast<int>(d_tables.size()) - 1;
}

void slab_echo::check_table(int id, const char* what) const
{
    if (id < -1 || id >= static_cast<int>(d_tables.size()))
        throw std::invalid_argument(std::string("slab_echo: ") + what + " " +
                                    std::to_string(id) + " is not a registered table (" +
                                    std::to_string(d_tables.size()) +
                                    " registered, -1: none)");
}

void slab_echo::multiply_by(std::complex<double>* g, int id, double cos_incidence) const
{
    const table_type& t = d_tables[id];
    const int last = static_cast<int>(t.rows()) - 1;
    double position =
        std::acos(std::min(1.0, std::max(0.0, cos_incidence))) * (last / (M_PI / 2.0));
    if (!std::isfinite(position))
        position = 0.0; // a NaN cosine (a zero-length leg) cannot index the table
    const int index = std::min(static_cast<int>(position), last - 1);
    const double frac = position - index;
    // complex arithmetic written out on the (re, im) pairs: std::complex's operator*
    // checks for NaN on every product, which keeps the loop from vectorising
    const double* lo = reinterpret_cast<const double*>(t.row(index).data());
    const double* hi = reinterpret_cast<const double*>(t.row(index + 1).data());
    double* out = reinterpret_cast<double*>(g);
    const int n = static_cast<int>(d_k.size());
    for (int i = 0; i < n; i++) {
        const double re = lo[2 * i] + frac * (hi[2 * i] - lo[2 * i]);
        const double im = lo[2 * i + 1] + frac * (hi[2 * i + 1] - lo[2 * i + 1]);
        const double gr = out[2 * i], gi = out[2 * i + 1];
        out[2 * i] = gr * re - gi * im;
        out[2 * i + 1] = gr * im + gi * re;
    }
}

void slab_echo::phase_ramp(double length_m, std::complex<double>* e) const
{
    const int N = static_cast<int>(d_k.size());
    if (!d_uniform) {
        for (int i = 0; i < N; i++)
            e[i] = std::polar(1.0, -length_m * d_k[i]);
        return;
    }
    // e^{−j k_n L} = e^{−j k_b L} · e^{−j j Δk L} for n = b + j: two exact phases a pair,
    // the first block's powers of the step and each block's start from the one before
    // (the products within a block are independent of each other; at most 16 + N/16
    // rotations chained, ~1e-14 off the exact phase)
    std::complex<double> powers[exact_every];
    powers[0] = 1.0;
    const std::complex<double> step = std::polar(1.0, -length_m * d_dk);
    for (int j = 1; j < exact_every; j++)
        powers[j] = powers[j - 1] * step;
    const std::complex<double> block_step = powers[exact_every - 1] * step;
    const double* pp = reinterpret_cast<const double*>(powers);
    double* ep = reinterpret_cast<double*>(e);
    std::complex<double> start = std::polar(1.0, -length_m * d_k[0]);
    for (int b = 0; b < N; b += exact_every) {
        const double br = start.real(), bi = start.imag();
        const int count = std::min(exact_every, N - b);
        for (int j = 0; j < count; j++) {
            ep[2 * (b + j)] = br * pp[2 * j] - bi * pp[2 * j + 1];
            ep[2 * (b + j) + 1] = br * pp[2 * j + 1] + bi * pp[2 * j];
        }
        start *= block_step;
    }
}

void slab_echo::add_path(double length_m,
                         std::complex<double> scale,
                         std::complex<double>* g,
                         std::complex<double>* e,
                         std::complex<double>* out_row) const
{
    const int N = static_cast<int>(d_k.size());
    phase_ramp(length_m, e);
    const double sr = scale.real(), si = scale.imag();
    const double* gp = reinterpret_cast<const double*>(g);
    const double* ep = reinterpret_cast<const double*>(e);
    double* row = reinterpret_cast<double*>(out_row);
    for (int i = 0; i < N; i++) {
        const double ar = gp[2 * i] * ep[2 * i] - gp[2 * i + 1] * ep[2 * i + 1];
        const double ai = gp[2 * i] * ep[2 * i + 1] + gp[2 * i + 1] * ep[2 * i];
        row[2 * i] += sr * ar - si * ai;
        row[2 * i + 1] += sr * ai + si * ar;
    }
}

void slab_echo::scale_by_wavelength(table_type& out) const
{
    for (Eigen::Index m = 0; m < out.rows(); m++)
        for (Eigen::Index i = 0; i < out.cols(); i++)
            out(m, i) *= d_lambda[i];
}

void slab_echo::check_weights(const Eigen::VectorXcd& tx_weights) const
{
    if (tx_weights.size() != d_tx.rows())
        throw std::invalid_argument("slab_echo: " + std::to_string(tx_weights.size()) +
                                    " TX weights for " + std::to_string(d_tx.rows()) +
                                    " TX elements");
}

slab_echo::table_type slab_echo::echo(const Eigen::Vector2d& face_point_m,
                                      const Eigen::Vector2d& normal,
                                      int gamma_table,
                                      const Eigen::VectorXcd& tx_weights,
                                      const Eigen::MatrixXd& crossed_points_m,
                                      const Eigen::MatrixXd& crossed_normals,
                                      const std::vector<int>& crossed_tables) const
{
    const int K = d_tx.rows(), M = d_rx.rows(), N = static_cast<int>(d_k.size());
    check_weights(tx_weights);
    const double norm = std::hypot(normal(0), normal(1));
    if (!(norm > 0.0) || !std::isfinite(norm) || !face_point_m.allFinite())
        throw std::invalid_argument(
            "slab_echo: the wall needs a finite face point and a nonzero normal");
    check_table(gamma_table, "gamma_table");
    const int C = static_cast<int>(crossed_tables.size());
    if (crossed_points_m.rows() != C || crossed_normals.rows() != C ||
        (C > 0 && (crossed_points_m.cols() != 2 || crossed_normals.cols() != 2)))
        throw std::invalid_argument(
            "slab_echo: crossed walls: points and normals must be (" + std::to_string(C) +
            ", 2), one row per table id");
    std::vector<Eigen::Vector2d> q2(C), n2(C);
    for (int c = 0; c < C; c++) {
        check_table(crossed_tables[c], "crossed table");
        q2[c] = crossed_points_m.row(c).transpose();
        n2[c] = crossed_normals.row(c).transpose();
        const double l = n2[c].norm();
        if (crossed_tables[c] >= 0 && !(l > 0.0 && std::isfinite(l) && q2[c].allFinite()))
            throw std::invalid_argument("slab_echo: crossed wall " + std::to_string(c) +
                                        " needs a finite point and a nonzero normal");
        if (l > 0.0)
            n2[c] /= l;
    }

    const Eigen::Vector2d n = normal / norm;
    const Eigen::Vector2d& q = face_point_m;
    table_type out = table_type::Zero(M, N);
    std::vector<std::complex<double>> g(N), e(N);

    for (int k = 0; k < K; k++) {
        const Eigen::Vector2d tx = d_tx.row(k).transpose();
        const Eigen::Vector2d image = tx - 2.0 * (tx - q).dot(n) * n;
        const std::complex<double> w = tx_weights(k);
        for (int m = 0; m < M; m++) {
            const Eigen::Vector2d rx = d_rx.row(m).transpose();
            const Eigen::Vector2d v = rx - image;
            const double length_m = v.norm();
            const double vn = v.dot(n);
            // Γ at this pair's incidence
            if (gamma_table < 0)
                std::fill(g.begin(), g.end(), std::complex<double>(-1.0, 0.0));
            else {
                std::fill(g.begin(), g.end(), std::complex<double>(1.0, 0.0));
                multiply_by(g.data(), gamma_table, std::abs(vn) / length_m);
            }
            // T of each wall a leg crosses, at the leg's incidence
            if (C > 0) {
                const Eigen::Vector2d bounce = image + ((q - image).dot(n) / vn) * v;
                const Eigen::Vector2d ends[2][2] = { { tx, bounce }, { bounce, rx } };
                for (int c = 0; c < C; c++) {
                    if (crossed_tables[c] < 0)
                        continue;
                    for (const auto& leg : ends) {
                        const double side_a = (leg[0] - q2[c]).dot(n2[c]);
                        const double side_b = (leg[1] - q2[c]).dot(n2[c]);
                        if (!(side_a * side_b < 0.0))
                            continue;
                        const Eigen::Vector2d d = leg[1] - leg[0];
                        multiply_by(g.data(),
                                    crossed_tables[c],
                                    std::abs(d.dot(n2[c])) / d.norm());
                    }
                }
            }
            // e^{−j k_n L} / (4π L), weighted
            add_path(length_m,
                     w / (4.0 * M_PI * length_m),
                     g.data(),
                     e.data(),
                     out.row(m).data());
        }
    }
    scale_by_wavelength(out);
    return out;
}

namespace {
Eigen::Vector2d unit_normal(const Eigen::Vector2d& normal, const char* what)
{
    const double norm = std::hypot(normal(0), normal(1));
    if (!(norm > 0.0) || !std::isfinite(norm))
        throw std::invalid_argument(std::string("slab_echo: ") + what +
                                    " must be finite and nonzero");
    return normal / norm;
}

Eigen::Vector2d
mirrored(const Eigen::Vector2d& p, const Eigen::Vector2d& q, const Eigen::Vector2d& n)
{
    return p - 2.0 * (p - q).dot(n) * n;
}
} // namespace

template <typename Valid>
void slab_echo::add_doubles(const Eigen::Vector2d& q1,
                            const Eigen::Vector2d& n1,
                            const Eigen::Vector2d& q2,
                            const Eigen::Vector2d& n2,
                            int gamma_table,
                            const Eigen::VectorXcd& tx_weights,
                            Valid valid,
                            table_type& out) const
{
    const int K = d_tx.rows(), M = d_rx.rows(), N = static_cast<int>(d_k.size());
    std::vector<std::complex<double>> g(N), e(N);
    for (int k = 0; k < K; k++) {
        const Eigen::Vector2d image1 = mirrored(d_tx.row(k).transpose(), q1, n1);
        const Eigen::Vector2d image12 = mirrored(image1, q2, n2);
        for (int m = 0; m < M; m++) {
            // the last leg's line from TX's double image to the RX element, the second
            // bounce on it, the middle leg's line from TX's first image through that
            // bounce
            const Eigen::Vector2d v = d_rx.row(m).transpose() - image12;
            const double length_m = v.norm();
            const double t2 = (q2 - image12).dot(n2) / v.dot(n2);
            const Eigen::Vector2d second = image12 + t2 * v;
            const Eigen::Vector2d w = second - image1;
            const double t1 = (q1 - image1).dot(n1) / w.dot(n1);
            const Eigen::Vector2d first = image1 + t1 * w;
            if (!(t2 > 0.0 && t2 < 1.0 && t1 > 0.0 && t1 < 1.0) ||
                !valid(k, m, first, second))
                continue;
            std::fill(
                g.begin(), g.end(), std::complex<double>(1.0, 0.0)); // a conductor: (−1)²
            if (gamma_table >= 0) {
                multiply_by(g.data(), gamma_table, std::abs(w.dot(n1)) / w.norm());
                multiply_by(g.data(), gamma_table, std::abs(v.dot(n2)) / length_m);
            }
            add_path(length_m,
                     tx_weights(k) / (4.0 * M_PI * length_m),
                     g.data(),
                     e.data(),
                     out.row(m).data());
        }
    }
}

slab_echo::table_type slab_echo::double_echo(const Eigen::Vector2d& first_point_m,
                                             const Eigen::Vector2d& first_normal,
                                             const Eigen::Vector2d& second_point_m,
                                             const Eigen::Vector2d& second_normal,
                                             int gamma_table,
                                             const Eigen::VectorXcd& tx_weights) const
{
    check_weights(tx_weights);
    check_table(gamma_table, "gamma_table");
    if (!first_point_m.allFinite() || !second_point_m.allFinite())
        throw std::invalid_argument(
            "slab_echo: double_echo's face points must be finite");
    const Eigen::Vector2d n1 = unit_normal(first_normal, "double_echo's first normal");
    const Eigen::Vector2d n2 = unit_normal(second_normal, "double_echo's second normal");
    const Eigen::Vector2d &q1 = first_point_m, &q2 = second_point_m;
    const int M = d_rx.rows(), N = static_cast<int>(d_k.size());
    table_type out = table_type::Zero(M, N);
    add_doubles(
        q1,
        n1,
        q2,
        n2,
        gamma_table,
        tx_weights,
        [&](int k, int m, const Eigen::Vector2d& first, const Eigen::Vector2d& second) {
            // both bounces on the faces' front sides, the TX element in front of
            // face 1 and the RX element in front of face 2
            return (second - q1).dot(n1) > 0.0 && (first - q2).dot(n2) > 0.0 &&
                   (d_tx.row(k).transpose() - q1).dot(n1) > 0.0 &&
                   (d_rx.row(m).transpose() - q2).dot(n2) > 0.0;
        },
        out);
    scale_by_wavelength(out);
    return out;
}

slab_echo::table_type slab_echo::corner_echo(const Eigen::Vector2d& corner_m,
                                             const Eigen::Vector2d& normal_a,
                                             const Eigen::Vector2d& normal_b,
                                             int gamma_table,
                                             const Eigen::VectorXcd& tx_weights) const
{
    check_weights(tx_weights);
    check_table(gamma_table, "gamma_table");
    if (!corner_m.allFinite())
        throw std::invalid_argument("slab_echo: corner_echo's corner must be finite");
    const Eigen::Vector2d n_a = unit_normal(normal_a, "corner_echo's normal_a");
    const Eigen::Vector2d n_b = unit_normal(normal_b, "corner_echo's normal_b");
    const Eigen::Vector2d& c = corner_m;
    // each face runs from the corner into the side the other one faces
    Eigen::Vector2d d_a(-n_a(1), n_a(0)), d_b(-n_b(1), n_b(0));
    if (!(d_a.dot(n_b) > 0.0))
        d_a = -d_a;
    if (!(d_b.dot(n_a) > 0.0))
        d_b = -d_b;
    const int K = d_tx.rows(), M = d_rx.rows(), N = static_cast<int>(d_k.size());
    // both arrays' elements in front of both faces (inside the room)
    std::vector<char> tx_in(K), rx_in(M);
    for (int k = 0; k < K; k++) {
        const Eigen::Vector2d p = d_tx.row(k).transpose() - c;
        tx_in[k] = p.dot(n_a) > 0.0 && p.dot(n_b) > 0.0;
    }
    for (int m = 0; m < M; m++) {
        const Eigen::Vector2d p = d_rx.row(m).transpose() - c;
        rx_in[m] = p.dot(n_a) > 0.0 && p.dot(n_b) > 0.0;
    }
    table_type out = table_type::Zero(M, N);
    const Eigen::Vector2d* orders[2][4] = { { &n_a, &d_a, &n_b, &d_b },
                                            { &n_b, &d_b, &n_a, &d_a } };
    for (const auto& o : orders) {
        const Eigen::Vector2d &n1 = *o[0], &d1 = *o[1], &n2 = *o[2], &d2 = *o[3];
        add_doubles(
            c,
            n1,
            c,
            n2,
            gamma_table,
            tx_weights,
            [&](int k,
                int m,
                const Eigen::Vector2d& first,
                const Eigen::Vector2d& second) {
                return tx_in[k] && rx_in[m] && (second - c).dot(d2) >= 0.0 &&
                       (first - c).dot(d1) >= 0.0;
            },
            out);
    }
    scale_by_wavelength(out);
    return out;
}

namespace {
// bistatic.segment_crosses: whether segment p0 → p1 properly crosses segment a → b
bool segment_crosses(double p0x,
                     double p0y,
                     double p1x,
                     double p1y,
                     double ax,
                     double ay,
                     double bx,
                     double by)
{
    const double d1 = (bx - ax) * (p0y - ay) - (by - ay) * (p0x - ax);
    const double d2 = (bx - ax) * (p1y - ay) - (by - ay) * (p1x - ax);
    if (!(d1 * d2 < 0.0))
        return false;
    const double d3 = (p1x - p0x) * (ay - p0y) - (p1y - p0y) * (ax - p0x);
    const double d4 = (p1x - p0x) * (by - p0y) - (p1y - p0y) * (bx - p0x);
    return d3 * d4 < 0.0;
}
} // namespace

Eigen::VectorXd slab_echo::trial_energies(const Eigen::Vector3d& pose,
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
                                          const cmatrix_ref& rows) const
{
    const int M = d_rx.rows(), N = static_cast<int>(d_k.size());
    const Eigen::Index MN = static_cast<Eigen::Index>(M) * N;
    check_weights(tx_weights);
    check_table(gamma_table, "gamma_table");
    check_table(blocker_table, "blocker_table");
    if (trials.rows() > 0 && trials.cols() != 2)
        throw std::invalid_argument(
            "slab_echo: trials must be (T, 2): offset_m, rotation_rad; got (" +
            std::to_string(trials.rows()) + ", " + std::to_string(trials.cols()) + ")");
    const Eigen::Index C = blocker_ends_m.rows();
    if ((C > 0 && blocker_ends_m.cols() != 4) || blocker_points_m.rows() != C ||
        blocker_normals.rows() != C ||
        (C > 0 && (blocker_points_m.cols() != 2 || blocker_normals.cols() != 2)))
        throw std::invalid_argument(
            "slab_echo: blockers: ends must be (C, 4), points and normals (C, 2); got " +
            std::to_string(C) + " ends, " + std::to_string(blocker_points_m.rows()) +
            " points, " + std::to_string(blocker_normals.rows()) + " normals");
    if (system_response.size() != N)
        throw std::invalid_argument("slab_echo: system_response must have " +
                                    std::to_string(N) + " subcarriers, got " +
                                    std::to_string(system_response.size()));
    if (rows.cols() != MN || (basis.cols() > 0 && basis.rows() != MN))
        throw std::invalid_argument(
            "slab_echo: rows must be (F, " + std::to_string(MN) + ") and basis (" +
            std::to_string(MN) + ", B); got rows (" + std::to_string(rows.rows()) + ", " +
            std::to_string(rows.cols()) + "), basis (" + std::to_string(basis.rows()) +
            ", " + std::to_string(basis.cols()) + ")");
    if (!pose.allFinite() || !wall_centre_m.allFinite() || !wall_normal.allFinite() ||
        !pivot_m.allFinite() || !trials.allFinite())
        throw std::invalid_argument(
            "slab_echo: trial_energies needs a finite pose, wall, pivot and trials");

    // bistatic.world_to_robot, robot_to_world and rotate(v, -heading), on the same floats
    const double x = pose(0), y = pose(1);
    const double c = std::cos(pose(2)), s = std::sin(pose(2));
    const double c_back = std::cos(-pose(2)), s_back = std::sin(-pose(2));
    auto to_robot = [&](double px, double py) {
        px -= x;
        py -= y;
        return Eigen::Vector2d(c * px + s * py, -s * px + c * py);
    };
    auto to_world = [&](double px, double py) {
        return Eigen::Vector2d(x + c * px - s * py, y + s * px + c * py);
    };
    auto turn_back = [&](double vx, double vy) {
        return Eigen::Vector2d(c_back * vx - s_back * vy, s_back * vx + c_back * vy);
    };
    const Eigen::Vector2d tx_w = to_world(tx_centre_m(0), tx_centre_m(1));
    const Eigen::Vector2d rx_w = to_world(rx_centre_m(0), rx_centre_m(1));
    Eigen::MatrixXd blocker_points_r(C, 2), blocker_normals_r(C, 2);
    for (Eigen::Index b = 0; b < C; b++) {
        blocker_points_r.row(b) =
            to_robot(blocker_points_m(b, 0), blocker_points_m(b, 1)).transpose();
        blocker_normals_r.row(b) =
            turn_back(blocker_normals(b, 0), blocker_normals(b, 1)).transpose();
    }

    const Eigen::Index T = trials.rows();
    Eigen::VectorXd energies = Eigen::VectorXd::Zero(T);
    std::vector<Eigen::Index> seen;
    Eigen::MatrixXcd echoes(T, MN);
    const double tx_x = tx_centre_m(0), tx_y = tx_centre_m(1), rx_x = rx_centre_m(0),
                 rx_y = rx_centre_m(1);
    for (Eigen::Index t = 0; t < T; t++) {
        // wall_refinement._moved_wall
        const double cr = std::cos(trials(t, 1)), sr = std::sin(trials(t, 1));
        const double nx = cr * wall_normal(0) - sr * wall_normal(1);
        const double ny = sr * wall_normal(0) + cr * wall_normal(1);
        const double rel_x = wall_centre_m(0) - pivot_m(0),
                     rel_y = wall_centre_m(1) - pivot_m(1);
        const double centre_x =
            pivot_m(0) + (cr * rel_x - sr * rel_y) + trials(t, 0) * nx;
        const double centre_y =
            pivot_m(1) + (sr * rel_x + cr * rel_y) + trials(t, 0) * ny;
        // the robot on the face's side
        if (!((x - centre_x) * nx + (y - centre_y) * ny > 0.0))
            continue;
        // bistatic.specular_path in the robot frame
        const Eigen::Vector2d q = to_robot(centre_x, centre_y);
        const Eigen::Vector2d normal_r = turn_back(nx, ny);
        double un_x = normal_r(0), un_y = normal_r(1);
        const double length = std::sqrt(un_x * un_x + un_y * un_y);
        if (length != 0.0) {
            un_x /= length;
            un_y /= length;
        }
        if (!((tx_x - q(0)) * un_x + (tx_y - q(1)) * un_y > 0.0 &&
              (rx_x - q(0)) * un_x + (rx_y - q(1)) * un_y > 0.0))
            continue;
        const double d = 2.0 * ((tx_x - q(0)) * un_x + (tx_y - q(1)) * un_y);
        const double v_x = tx_x - d * un_x - rx_x, v_y = tx_y - d * un_y - rx_y;
        const double along_v =
            ((q(0) - rx_x) * un_x + (q(1) - rx_y) * un_y) / (v_x * un_x + v_y * un_y);
        const Eigen::Vector2d spec = to_world(rx_x + along_v * v_x, rx_y + along_v * v_y);
        // within the wall's extent along (−n_y, n_x)
        const double along = (spec(0) - centre_x) * -ny + (spec(1) - centre_y) * nx;
        if (!(t_min_m <= along && along <= t_max_m))
            continue;
        std::vector<int> crossed;
        for (Eigen::Index b = 0; b < C; b++) {
            const double ax = blocker_ends_m(b, 0), ay = blocker_ends_m(b, 1);
            const double bx = blocker_ends_m(b, 2), by = blocker_ends_m(b, 3);
            if (segment_crosses(tx_w(0), tx_w(1), spec(0), spec(1), ax, ay, bx, by) ||
                segment_crosses(spec(0), spec(1), rx_w(0), rx_w(1), ax, ay, bx, by))
                crossed.push_back(static_cast<int>(b));
        }
        Eigen::MatrixXd cross_points(crossed.size(), 2), cross_normals(crossed.size(), 2);
        std::vector<int> cross_tables(crossed.size(), blocker_table);
        for (size_t i = 0; i < crossed.size(); i++) {
            cross_points.row(i) = blocker_points_r.row(crossed[i]);
            cross_normals.row(i) = blocker_normals_r.row(crossed[i]);
        }
        const table_type e = echo(q,
                                  normal_r,
                                  gamma_table,
                                  tx_weights,
                                  cross_points,
                                  cross_normals,
                                  cross_tables);
        const Eigen::Index r = static_cast<Eigen::Index>(seen.size());
        for (int m = 0; m < M; m++)
            for (int n = 0; n < N; n++)
                echoes(r, static_cast<Eigen::Index>(m) * N + n) =
                    e(m, n) * system_response(n);
        seen.push_back(t);
    }
    if (seen.empty())
        return energies;
    Eigen::MatrixXcd projected = echoes.topRows(seen.size());
    if (basis.cols() > 0)
        projected -= (projected * basis.conjugate()) * basis.transpose();
    const Eigen::VectorXd norms = projected.rowwise().squaredNorm();
    const Eigen::VectorXd captured =
        (projected.conjugate() * rows.transpose()).cwiseAbs2().rowwise().sum();
    for (size_t i = 0; i < seen.size(); i++)
        energies(seen[i]) = norms(i) > 0.0 ? captured(i) / norms(i) : 0.0;
    return energies;
}

} // namespace thrumapper
} // namespace gr
