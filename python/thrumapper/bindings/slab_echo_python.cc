/*
 * SPDX-License-Identifier: GPL-3.0-or-later
 */
/* Hand-written bindings: gr_modtool bind is not used (see tools/update_binding_hashes.py). */
/* BINDTOOL_GEN_AUTOMATIC(0) */
/* BINDTOOL_USE_PYGCCXML(0) */
/* BINDTOOL_HEADER_FILE(slab_echo.h) */
/* BINDTOOL_HEADER_FILE_HASH(476b122b408347153f2227fe9455b9c2) */

#include <pybind11/complex.h>
#include <pybind11/eigen.h>
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

namespace py = pybind11;

#include <gnuradio/thrumapper/slab_echo.h>

void bind_slab_echo(py::module& m)
{
    using namespace gr::thrumapper;
    py::class_<slab_echo>(m, "slab_echo", R"doc(
The CSI of one wall's specular echo, element pair by element pair: image method, spherical
wavefronts, the slab's Γ at each pair's incidence, the insertion transmission T of each wall a
leg crosses (the core of echo_model.EchoModel.echo_csi; system delay left out, robot frame).

    core = thrumapper.slab_echo(tx_elements_m, rx_elements_m, 2.44e9, offsets_hz)
    gamma, t = building_sim.coefficient_table(material, 2.44e9 + offsets_hz)
    g, tr = core.add_table(gamma), core.add_table(t)
    h = core.echo([0.0, -1.125], [0.0, 1.0], g, weights)            # (M, N)
    h = core.echo(face, normal, g, weights, [[0, 1.0]], [[0, -1.0]], [tr])   # behind a wall

    h = core.double_echo(q1, n1, q2, n2, g, weights)  # TX -> face 1 -> face 2 -> RX
    h = core.corner_echo(corner, normal_a, normal_b, g, weights)  # a room's inside corner
    j = core.trial_energies(pose, tx_c, rx_c, centre, normal, t0, t1, pivot, trials, g, weights,
                            ends, points, normals, tr, system_response, basis, rows)  # fits' J

gamma_table -1 is a perfect conductor (Γ = -1); a crossed wall with table -1 is ignored.
)doc")
        .def(py::init<const Eigen::MatrixXd&, const Eigen::MatrixXd&, double, const std::vector<double>&>(),
             py::arg("tx_elements_m"),
             py::arg("rx_elements_m"),
             py::arg("carrier_hz"),
             py::arg("subcarrier_offsets_hz"))
        .def("add_table", &slab_echo::add_table, py::arg("table"))
        .def("echo",
             &slab_echo::echo,
             py::arg("face_point_m"),
             py::arg("normal"),
             py::arg("gamma_table"),
             py::arg("tx_weights"),
             py::arg("crossed_points_m") = Eigen::MatrixXd(0, 2),
             py::arg("crossed_normals") = Eigen::MatrixXd(0, 2),
             py::arg("crossed_tables") = std::vector<int>())
        .def("double_echo",
             &slab_echo::double_echo,
             py::arg("first_point_m"),
             py::arg("first_normal"),
             py::arg("second_point_m"),
             py::arg("second_normal"),
             py::arg("gamma_table"),
             py::arg("tx_weights"))
        .def("corner_echo",
             &slab_echo::corner_echo,
             py::arg("corner_m"),
             py::arg("normal_a"),
             py::arg("normal_b"),
             py::arg("gamma_table"),
             py::arg("tx_weights"))
        .def("trial_energies",
             &slab_echo::trial_energies,
             py::arg("pose"),
             py::arg("tx_centre_m"),
             py::arg("rx_centre_m"),
             py::arg("wall_centre_m"),
             py::arg("wall_normal"),
             py::arg("t_min_m"),
             py::arg("t_max_m"),
             py::arg("pivot_m"),
             py::arg("trials"),
             py::arg("gamma_table"),
             py::arg("tx_weights"),
             py::arg("blocker_ends_m"),
             py::arg("blocker_points_m"),
             py::arg("blocker_normals"),
             py::arg("blocker_table"),
             py::arg("system_response"),
             py::arg("basis"),
             py::arg("rows"),
             R"doc(
J of trial placements (offset_m, rotation_rad) of one wall at one pose: the CSI fit's objective
(wall_refinement.CsiWallRefiner._fit). Each trial turns the wall (world centre, unit normal)
about pivot_m and moves it along its new normal; its echo (robot frame of pose, times
system_response, flattened m*N + n) is projected away from basis (M*N, B; B = 0 for none) and
scored by the energy of rows (F, M*N) it captures with a free gain per frame. 0 where the pose
does not see the trial (extent t_min_m..t_max_m along (-n_y, n_x) from the centre). Legs that
cross a blocker segment (C, 4) take its face (points, normals (C, 2), T table blocker_table).
Returns (T,).
)doc")
        .def_property_readonly("num_tx", &slab_echo::num_tx)
        .def_property_readonly("num_rx", &slab_echo::num_rx)
        .def_property_readonly("num_subcarriers", &slab_echo::num_subcarriers)
        .def_property_readonly("uniform_subcarriers", &slab_echo::uniform_subcarriers);
}
