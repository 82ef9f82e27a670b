/* -*- c++ -*- */
/*
 * SPDX-License-Identifier: GPL-3.0-or-later
 */
#include <gnuradio/thrumapper/slab_echo.h>
#include <boost/test/unit_test.hpp>
#include <cmath>
#include <stdexcept>

using namespace gr::thrumapper;
using cd = std::complex<double>;

namespace {
const double c_m_s = 299792458.0;

std::vector<double> offsets(int n, double bandwidth_hz)
{
    std::vector<double> out(n);
    for (int i = 0; i < n; i++)
        out[i] = (i - n / 2) * bandwidth_hz / n;
    return out;
}

Eigen::MatrixXd point(double x, double y)
{
    Eigen::MatrixXd p(1, 2);
    p << x, y;
    return p;
}

slab_echo::table_type constant_table(int rows, int n, cd value)
{
    return slab_echo::table_type::Constant(rows, n, value);
}
} // namespace

BOOST_AUTO_TEST_CASE(slab_echo_conductor_wall_delay_and_spreading)
{
    // One TX element at (-0.35, 0), one RX element at (0.35, 0), a metal wall whose face
    // is 2.2 m to the right (y = -2.2): the echo travels 2·sqrt(2.2² + 0.35²) m, so its
    // phase falls by 2π·Δf·L/c per subcarrier and its amplitude is λ/(4πL) (free-space
    // spreading from the TX image), with Γ = -1.
    const int n = 64;
    slab_echo core(point(-0.35, 0.0), point(0.35, 0.0), 2.44e9, offsets(n, 120e6));
    BOOST_CHECK(core.uniform_subcarriers());
    Eigen::VectorXcd w(1);
    w << cd(1.0, 0.0);
    const auto h = core.echo(Eigen::Vector2d(0.3, -2.2),
                             Eigen::Vector2d(0.0, 1.0),
                             -1,
                             w,
                             Eigen::MatrixXd(0, 2),
                             Eigen::MatrixXd(0, 2),
                             {});
    BOOST_REQUIRE_EQUAL(h.rows(), 1);
    BOOST_REQUIRE_EQUAL(h.cols(), n);
    const double length_m = 2.0 * std::hypot(2.2, 0.35);
    const double step_hz = 120e6 / n;
    for (int i = 0; i + 1 < n; i++) {
        const double dphi = std::arg(h(0, i + 1) / h(0, i));
        BOOST_CHECK_SMALL(
            std::remainder(dphi + 2.0 * M_PI * step_hz * length_m / c_m_s, 2.0 * M_PI),
            1e-9);
    }
    for (int i = 0; i < n; i++) {
        const double f_hz = 2.44e9 + (i - n / 2) * step_hz;
        BOOST_CHECK_CLOSE(
            std::abs(h(0, i)), c_m_s / f_hz / (4.0 * M_PI * length_m), 1e-9);
        // the absolute phase: -1 (metal) times e^{-j2πfL/c}
        const cd expected = -std::polar(1.0, -2.0 * M_PI * f_hz * length_m / c_m_s);
        BOOST_CHECK_SMALL(std::abs(h(0, i) / std::abs(h(0, i)) - expected), 1e-9);
    }
}

BOOST_AUTO_TEST_CASE(slab_echo_fast_phase_ramp_is_exact)
{
    // 8 + 8 elements on two circles, 256 subcarriers: the rotation per subcarrier
    // (uniform subcarriers) and one sin/cos each (the same subcarriers moved by 1 mHz,
    // not uniform) give the same echo to 1e-12 of its size.
    Eigen::MatrixXd tx(8, 2), rx(8, 2);
    for (int i = 0; i < 8; i++) {
        tx.row(i) << -0.35 + 0.08 * std::cos(i * M_PI / 4), 0.08 * std::sin(i * M_PI / 4);
        rx.row(i) << 0.35 + 0.08 * std::cos(i * M_PI / 4), 0.08 * std::sin(i * M_PI / 4);
    }
    auto uniform = offsets(256, 120e6);
    auto jittered = uniform;
    jittered[7] += 1e-3;
    slab_echo a(tx, rx, 2.44e9, uniform), b(tx, rx, 2.44e9, jittered);
    BOOST_CHECK(a.uniform_subcarriers());
    BOOST_CHECK(!b.uniform_subcarriers());
    Eigen::VectorXcd w(8);
    for (int i = 0; i < 8; i++)
        w(i) = std::polar(0.3 + 0.1 * i, 0.7 * i);
    const Eigen::Vector2d q(1.0, 6.5), n(-0.3, -1.0); // a skewed wall 6.5 m away
    const auto ha = a.echo(q, n, -1, w, Eigen::MatrixXd(0, 2), Eigen::MatrixXd(0, 2), {});
    const auto hb = b.echo(q, n, -1, w, Eigen::MatrixXd(0, 2), Eigen::MatrixXd(0, 2), {});
    double worst = 0.0;
    for (int m = 0; m < 8; m++)
        for (int i = 0; i < 256; i++)
            if (i != 7)
                worst = std::max(worst, std::abs(ha(m, i) - hb(m, i)));
    BOOST_CHECK_SMALL(worst / ha.norm(), 1e-12);
}

BOOST_AUTO_TEST_CASE(slab_echo_tables_and_crossed_walls)
{
    const int n = 32;
    slab_echo core(point(-0.35, 0.0), point(0.35, 0.0), 2.44e9, offsets(n, 120e6));
    Eigen::VectorXcd w(1);
    w << cd(1.0, 0.0);
    const Eigen::MatrixXd none(0, 2);
    const Eigen::Vector2d face(0.0, -2.2), up(0.0, 1.0);
    const auto metal = core.echo(face, up, -1, w, none, none, {});
    // Γ linear in the incidence angle, 0 at normal incidence and 1 at grazing: this pair
    // sees the wall at atan(0.35 / 2.2) from its normal
    slab_echo::table_type ramp(91, n);
    for (int r = 0; r < 91; r++)
        ramp.row(r).setConstant(cd(r / 90.0, 0.0));
    const int gamma = core.add_table(ramp);
    const auto h = core.echo(face, up, gamma, w, none, none, {});
    const double incidence = std::atan2(0.35, 2.2) / (M_PI / 2.0);
    BOOST_CHECK_SMALL((h + incidence * metal).norm() / metal.norm(), 1e-9);
    // a wall of transmission 0.5 at y = -1: both legs cross it (0.25); at y = +1, behind
    // the radar, neither does; one from (0, -3) to ... across the bounce's leg only: a
    // wall along x = 0.1 cuts the leg bounce -> RX (the bounce is at x = 0), not TX ->
    // bounce
    const int half = core.add_table(constant_table(2, n, cd(0.5, 0.0)));
    const auto both =
        core.echo(face, up, -1, w, point(0.0, -1.0), point(0.0, 1.0), { half });
    BOOST_CHECK_SMALL((both - 0.25 * metal).norm() / metal.norm(), 1e-12);
    const auto neither =
        core.echo(face, up, -1, w, point(0.0, 1.0), point(0.0, 1.0), { half });
    BOOST_CHECK_SMALL((neither - metal).norm() / metal.norm(), 1e-12);
    const auto one =
        core.echo(face, up, -1, w, point(0.1, 0.0), point(1.0, 0.0), { half });
    BOOST_CHECK_SMALL((one - 0.5 * metal).norm() / metal.norm(), 1e-12);
    // table -1 for a crossed wall: ignored
    const auto ignored =
        core.echo(face, up, -1, w, point(0.0, -1.0), point(0.0, 1.0), { -1 });
    BOOST_CHECK_SMALL((ignored - metal).norm() / metal.norm(), 1e-12);
}

namespace {
// h, one RX element, against a path of length L with gain +1: phase −2πfL/c, size λ/(4πL)
void check_single_path(const slab_echo::table_type& h, double length_m, int n)
{
    for (int i = 0; i < n; i++) {
        const double f_hz = 2.44e9 + (i - n / 2) * 120e6 / n;
        const cd expected = std::polar(c_m_s / f_hz / (4.0 * M_PI * length_m),
                                       -2.0 * M_PI * f_hz * length_m / c_m_s);
        BOOST_CHECK_SMALL(std::abs(h(0, i) - expected) / std::abs(expected), 1e-9);
    }
}
} // namespace

BOOST_AUTO_TEST_CASE(slab_echo_double_bounce_between_metal_walls)
{
    // TX (−0.35, 0) → the metal wall y = −1 → the metal wall y = 1.3 → RX (0.35, 0): TX
    // imaged in both walls is (−0.35, 4.6), so the path is |(0.35, 0) − (−0.35, 4.6)|
    // long, with (−1)² = +1 for the two bounces
    const int n = 32;
    slab_echo core(point(-0.35, 0.0), point(0.35, 0.0), 2.44e9, offsets(n, 120e6));
    Eigen::VectorXcd w(1);
    w << cd(1.0, 0.0);
    const Eigen::Vector2d south(0.0, -1.0), north(0.0, 1.3), up(0.0, 1.0),
        down(0.0, -1.0);
    check_single_path(
        core.double_echo(south, up, north, down, -1, w), std::hypot(0.7, 4.6), n);
    // faces turned away from the radar: no such path
    BOOST_CHECK_EQUAL(core.double_echo(south, down, north, up, -1, w).norm(), 0.0);
}

BOOST_AUTO_TEST_CASE(slab_echo_corner_is_a_retro_reflector)
{
    // A room's inside corner at (2, −3), metal faces along y = −3 (toward −x) and x = 2
    // (toward +y), the radar inside: the path via face a then face b comes from TX's
    // point image through the corner, 2C − TX = (4.35, −6), and is |RX − (4.35, −6)|
    // long; the other order's bounces fall off the faces here
    const int n = 32;
    slab_echo core(point(-0.35, 0.0), point(0.35, 0.0), 2.44e9, offsets(n, 120e6));
    Eigen::VectorXcd w(1);
    w << cd(1.0, 0.0);
    const Eigen::Vector2d corner(2.0, -3.0), into_a(0.0, 1.0), into_b(-1.0, 0.0);
    check_single_path(
        core.corner_echo(corner, into_a, into_b, -1, w), std::hypot(4.0, 6.0), n);
    // the order of the faces does not matter
    const auto h = core.corner_echo(corner, into_a, into_b, -1, w);
    BOOST_CHECK_SMALL(
        (core.corner_echo(corner, into_b, into_a, -1, w) - h).norm() / h.norm(), 1e-12);
    // the radar outside the room (a face's normal turned away): nothing
    BOOST_CHECK_EQUAL(core.corner_echo(corner, into_a, -into_b, -1, w).norm(), 0.0);
    // Γ of a table: a constant 0.5 at both bounces gives a quarter
    const int half = core.add_table(constant_table(2, n, cd(0.5, 0.0)));
    BOOST_CHECK_SMALL(
        (core.corner_echo(corner, into_a, into_b, half, w) - 0.25 * h).norm() / h.norm(),
        1e-12);
}

BOOST_AUTO_TEST_CASE(slab_echo_bad_input)
{
    const int n = 16;
    slab_echo core(point(-0.35, 0.0), point(0.35, 0.0), 2.44e9, offsets(n, 120e6));
    Eigen::VectorXcd w(1), w2(2);
    w << cd(1.0, 0.0);
    w2 << cd(1.0, 0.0), cd(1.0, 0.0);
    const Eigen::MatrixXd none(0, 2);
    const Eigen::Vector2d face(0.0, -2.2), up(0.0, 1.0);
    BOOST_CHECK_THROW(core.echo(face, up, -1, w2, none, none, {}), std::invalid_argument);
    BOOST_CHECK_THROW(core.echo(face, Eigen::Vector2d(0.0, 0.0), -1, w, none, none, {}),
                      std::invalid_argument);
    BOOST_CHECK_THROW(core.echo(face, up, 3, w, none, none, {}), std::invalid_argument);
    BOOST_CHECK_THROW(core.echo(face, up, -1, w, point(0, 1), point(0, 1), { 0 }),
                      std::invalid_argument);
    BOOST_CHECK_THROW(core.echo(face, up, -1, w, none, none, { -1 }),
                      std::invalid_argument);
    BOOST_CHECK_THROW(core.corner_echo(face, up, Eigen::Vector2d(0.0, 0.0), -1, w),
                      std::invalid_argument);
    BOOST_CHECK_THROW(core.double_echo(face, up, face, -up, -1, w2),
                      std::invalid_argument);
    BOOST_CHECK_THROW(core.add_table(constant_table(1, n, cd(1.0, 0.0))),
                      std::invalid_argument);
    BOOST_CHECK_THROW(core.add_table(constant_table(4, n + 1, cd(1.0, 0.0))),
                      std::invalid_argument);
    BOOST_CHECK_THROW(core.add_table(constant_table(4, n, cd(NAN, 0.0))),
                      std::invalid_argument);
    BOOST_CHECK_THROW(
        slab_echo(Eigen::MatrixXd(1, 3), point(0, 0), 2.44e9, offsets(n, 120e6)),
        std::invalid_argument);
    BOOST_CHECK_THROW(slab_echo(point(0, 0), point(0, 0), 2.44e9, {}),
                      std::invalid_argument);
}

namespace {
// The ThruMapper layout: two 8-element rings of 8 cm, 0.7 m apart along the robot's x
// axis.
Eigen::MatrixXd ring(double centre_x)
{
    Eigen::MatrixXd r(8, 2);
    for (int i = 0; i < 8; i++)
        r.row(i) << centre_x + 0.08 * std::cos(2.0 * M_PI * i / 8),
            0.08 * std::sin(2.0 * M_PI * i / 8);
    return r;
}

struct trial_scene {
    static constexpr int n = 32;
    slab_echo core{ ring(-0.35), ring(0.35), 2.44e9, offsets(n, 120e6) };
    Eigen::VectorXcd weights = Eigen::VectorXcd::Ones(8);
    Eigen::VectorXcd system = Eigen::VectorXcd(n);
    // the robot at (2, 1) heading 0.3 rad; the wall's face y = -1.2, seen from above
    Eigen::Vector3d pose{ 2.0, 1.0, 0.3 };
    Eigen::Vector2d tx_c{ -0.35, 0.0 }, rx_c{ 0.35, 0.0 };
    Eigen::Vector2d centre{ 2.5, -1.2 }, normal{ 0.0, 1.0 };

    trial_scene()
    {
        const auto f = offsets(n, 120e6);
        for (int i = 0; i < n; i++)
            system(i) = std::polar(1.0, -2.0 * M_PI * (2.44e9 + f[i]) * 31e-9);
    }
    Eigen::Vector2d to_robot(const Eigen::Vector2d& p) const
    {
        return Eigen::Rotation2Dd(-pose(2)) * (p - pose.head<2>());
    }
    // one frame (1, M·N) of the wall through q (world) with normal nw seen from the pose
    Eigen::MatrixXcd
    frame(const Eigen::Vector2d& q,
          const Eigen::Vector2d& nw,
          int gamma = -1,
          const Eigen::MatrixXd& crossed_points_r = Eigen::MatrixXd(0, 2),
          const Eigen::MatrixXd& crossed_normals_r = Eigen::MatrixXd(0, 2),
          const std::vector<int>& tables = {}) const
    {
        const auto h = core.echo(to_robot(q),
                                 Eigen::Rotation2Dd(-pose(2)) * nw,
                                 gamma,
                                 weights,
                                 crossed_points_r,
                                 crossed_normals_r,
                                 tables);
        Eigen::MatrixXcd out(1, 8 * n);
        for (int m = 0; m < 8; m++)
            for (int i = 0; i < n; i++)
                out(0, m * n + i) = h(m, i) * system(i);
        return out;
    }
    // one trial_energies call: the wall, pivot, trials and data given, the rest defaulted
    // (no blockers, no basis, the scene's system response), each field free to change
    struct call {
        const trial_scene& s;
        Eigen::Vector2d centre, normal, pivot;
        Eigen::MatrixXd trials;
        Eigen::MatrixXcd rows;
        double t_min = -3.0, t_max = 3.0;
        int gamma = -1, blocker_table = -1;
        Eigen::MatrixXd ends = Eigen::MatrixXd(0, 4), points = Eigen::MatrixXd(0, 2),
                        normals = Eigen::MatrixXd(0, 2);
        Eigen::VectorXcd system = s.system;
        Eigen::MatrixXcd basis = Eigen::MatrixXcd(0, 0);

        Eigen::VectorXd run() const
        {
            return s.core.trial_energies(s.pose,
                                         s.tx_c,
                                         s.rx_c,
                                         centre,
                                         normal,
                                         t_min,
                                         t_max,
                                         pivot,
                                         trials,
                                         gamma,
                                         s.weights,
                                         ends,
                                         points,
                                         normals,
                                         blocker_table,
                                         system,
                                         basis,
                                         rows);
        }
    };
    call at(const Eigen::Vector2d& c,
            const Eigen::Vector2d& nw,
            const Eigen::Vector2d& pivot,
            const Eigen::MatrixXd& trials,
            const Eigen::MatrixXcd& rows) const
    {
        return call{ *this, c, nw, pivot, trials, rows };
    }
    Eigen::VectorXd energies(const Eigen::Vector2d& c,
                             const Eigen::Vector2d& nw,
                             const Eigen::Vector2d& pivot,
                             const Eigen::MatrixXd& trials,
                             const Eigen::MatrixXcd& rows,
                             double t_min = -3.0,
                             double t_max = 3.0) const
    {
        call one = at(c, nw, pivot, trials, rows);
        one.t_min = t_min;
        one.t_max = t_max;
        return one.run();
    }
};
} // namespace

BOOST_AUTO_TEST_CASE(slab_echo_trial_energies_peak_on_the_true_wall)
{
    // The data is the echo of the true wall. A map wall 12 cm in front of it is found by
    // the trial that moves it 12 cm back (−0.12 m along its normal, which faces the
    // robot), and one turned 3° about a point of the true face by the trial that turns it
    // back: each captures all of the data's energy (a free gain per frame), and every
    // other trial less.
    trial_scene s;
    const Eigen::MatrixXcd rows = s.frame(s.centre, s.normal);
    const double energy = rows.squaredNorm();
    Eigen::MatrixXd trials(5, 2);
    trials << -0.12, 0.0, 0.0, 0.0, -0.08, 0.0, -0.16, 0.0, -0.12, 0.02;
    const Eigen::Vector2d front = s.centre + 0.12 * s.normal;
    const auto moved = s.energies(front, s.normal, front, trials, rows);
    BOOST_CHECK_CLOSE(moved(0), energy, 1e-8);
    for (int t = 1; t < 5; t++)
        BOOST_CHECK_LT(moved(t), (1.0 - 1e-4) * moved(0));

    const double turn = 3.0 * M_PI / 180.0;
    const Eigen::Vector2d pivot(2.1, -1.2); // on the true face
    const Eigen::Rotation2Dd back(-turn);
    const Eigen::Vector2d turned_centre = pivot + back * (s.centre - pivot),
                          turned_normal = back * s.normal;
    Eigen::MatrixXd turns(3, 2);
    turns << 0.0, turn, 0.0, 0.0, 0.0, 2.0 * turn;
    const auto turned = s.energies(turned_centre, turned_normal, pivot, turns, rows);
    BOOST_CHECK_CLOSE(turned(0), energy, 1e-8);
    BOOST_CHECK_LT(turned(1), (1.0 - 1e-4) * turned(0));
    BOOST_CHECK_LT(turned(2), (1.0 - 1e-4) * turned(0));
    for (int t = 0; t < 3; t++)
        BOOST_CHECK_LE(turned(t),
                       energy * (1.0 + 1e-12)); // never more than the data holds
}

BOOST_AUTO_TEST_CASE(slab_echo_trial_energies_score_only_what_the_pose_sees)
{
    trial_scene s;
    const Eigen::MatrixXcd rows = s.frame(s.centre, s.normal);
    Eigen::MatrixXd trials(1, 2);
    trials << 0.0, 0.0;
    // the specular point lies near the robot's foot on the face, x ≈ 2.0 in the world,
    // 0.5 m before the centre along the direction (−n_y, n_x) = (−1, 0): an extent 1..3 m
    // along it from the centre misses it, one −1..3 m holds it
    BOOST_CHECK_EQUAL(s.energies(s.centre, s.normal, s.centre, trials, rows, 1.0, 3.0)(0),
                      0.0);
    BOOST_CHECK_GT(s.energies(s.centre, s.normal, s.centre, trials, rows, -1.0, 3.0)(0),
                   0.0);
    // the same face with its normal turned away from the robot: seen from behind, not at
    // all
    BOOST_CHECK_EQUAL(s.energies(s.centre, -s.normal, s.centre, trials, rows)(0), 0.0);
    // and none of a trial moved past the robot (the arrays behind the face)
    trials << 2.5, 0.0;
    BOOST_CHECK_EQUAL(s.energies(s.centre, s.normal, s.centre, trials, rows)(0), 0.0);
}

BOOST_AUTO_TEST_CASE(slab_echo_trial_energies_through_a_blocker_and_against_a_basis)
{
    // A hidden wall 1.5 m behind a corridor wall that delays what crosses it by 1 ns a
    // leg (a slab's group delay) and passes less of it the more oblique the leg: its echo
    // through the blocker has another shape than without it. Given the blocker's segment,
    // the trial at the true place captures all of the data; without it, or with a segment
    // the legs do not cross, less.
    trial_scene s;
    const int angles = 10;
    slab_echo::table_type t_table(angles, trial_scene::n);
    const auto f = offsets(trial_scene::n, 120e6);
    for (int a = 0; a < angles; a++)
        for (int i = 0; i < trial_scene::n; i++)
            t_table(a, i) =
                std::polar(0.9 - 0.8 * a / (angles - 1.0), -2.0 * M_PI * f[i] * 1e-9);
    const int t_id = s.core.add_table(t_table);
    const Eigen::Vector2d hidden_centre(2.5, -2.7), blocker_centre(2.0, -1.2);
    Eigen::MatrixXd blocker_r(1, 2), blocker_normal_r(1, 2);
    blocker_r.row(0) = s.to_robot(blocker_centre).transpose();
    blocker_normal_r.row(0) = (Eigen::Rotation2Dd(-s.pose(2)) * s.normal).transpose();
    const Eigen::MatrixXcd rows =
        s.frame(hidden_centre, s.normal, -1, blocker_r, blocker_normal_r, { t_id });
    const double energy = rows.squaredNorm();
    Eigen::MatrixXd trials(1, 2);
    trials << 0.0, 0.0;
    auto through = s.at(hidden_centre, s.normal, hidden_centre, trials, rows);
    through.t_min = -5.0;
    through.t_max = 5.0;
    through.blocker_table = t_id;
    through.points = blocker_centre.transpose();
    through.normals = s.normal.transpose();
    auto with = [&](double ax, double bx) {
        through.ends = Eigen::RowVector4d(ax, -1.2, bx, -1.2);
        return through.run()(0);
    };
    const double crossed = with(-3.0, 7.0), beside = with(8.0, 12.0);
    const double free =
        s.energies(hidden_centre, s.normal, hidden_centre, trials, rows)(0);
    BOOST_CHECK_CLOSE(crossed, energy, 1e-8);
    BOOST_CHECK_LT(free, 0.95 * energy);
    BOOST_CHECK_CLOSE(beside, free, 1e-10);

    // Against a basis (the corridor wall's own echo, normalised): the data projected away
    // from it, all of it captured by the true trial's echo projected the same way.
    Eigen::MatrixXcd basis = s.frame(blocker_centre, s.normal).transpose();
    basis /= basis.norm();
    const Eigen::MatrixXcd projected_rows =
        (rows.transpose() - basis * (basis.adjoint() * rows.transpose())).transpose();
    through.ends = Eigen::RowVector4d(-3.0, -1.2, 7.0, -1.2);
    through.basis = basis;
    through.rows = projected_rows;
    const double against = through.run()(0);
    BOOST_CHECK_CLOSE(against, projected_rows.squaredNorm(), 1e-8);
    BOOST_CHECK_LT(projected_rows.squaredNorm(), energy);
}

BOOST_AUTO_TEST_CASE(slab_echo_trial_energies_bad_input)
{
    trial_scene s;
    const Eigen::MatrixXcd rows = s.frame(s.centre, s.normal);
    Eigen::MatrixXd trials(1, 2), three(1, 3);
    trials << 0.0, 0.0;
    three << 0.0, 0.0, 0.0;
    BOOST_CHECK_THROW(s.energies(s.centre, s.normal, s.centre, three, rows),
                      std::invalid_argument);
    BOOST_CHECK_THROW(s.energies(s.centre, s.normal, s.centre, trials, rows.leftCols(10)),
                      std::invalid_argument);
    BOOST_CHECK_THROW(
        s.energies(Eigen::Vector2d(NAN, 0.0), s.normal, s.centre, trials, rows),
        std::invalid_argument);
    auto bad_ends = s.at(s.centre, s.normal, s.centre, trials, rows);
    bad_ends.ends = Eigen::MatrixXd(1, 3);
    bad_ends.points = Eigen::MatrixXd(1, 2);
    bad_ends.normals = Eigen::MatrixXd(1, 2);
    BOOST_CHECK_THROW(bad_ends.run(), std::invalid_argument);
    auto short_system = s.at(s.centre, s.normal, s.centre, trials, rows);
    short_system.system = s.system.head(5);
    BOOST_CHECK_THROW(short_system.run(), std::invalid_argument);
    auto unknown_table = s.at(s.centre, s.normal, s.centre, trials, rows);
    unknown_table.gamma = 7;
    BOOST_CHECK_THROW(unknown_table.run(), std::invalid_argument);
}
