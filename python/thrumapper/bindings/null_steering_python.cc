/*
 * SPDX-License-Identifier: GPL-3.0-or-later
 */
/* Hand-written bindings: gr_modtool bind is not used (see tools/update_binding_hashes.py). */
/* BINDTOOL_GEN_AUTOMATIC(0) */
/* BINDTOOL_USE_PYGCCXML(0) */
/* BINDTOOL_HEADER_FILE(null_steering.h) */
/* BINDTOOL_HEADER_FILE_HASH(fc8e1d831cc8da554b561d8f942e6843) */

#include <pybind11/complex.h>
#include <pybind11/eigen.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

namespace py = pybind11;

#include <gnuradio/thrumapper/null_steering.h>
#include <gnuradio/thrumapper/null_steering_weights.h>

void bind_null_steering(py::module& m)
{
    using namespace gr::thrumapper;
    py::class_<null_steering>(m, "null_steering", R"doc(
TX weights: a main lobe toward the walls, nulls toward the receiver and corners.

    ns = thrumapper.null_steering(radar)
    w = ns.design(math.radians(300), [], True)   # LCMV, near-field receiver null, whole band
    ns.coupling_db(w)                            # direct coupling vs a beam at the receiver, dB
    ns.expected_coupling_db(w, math.radians(2))  # with 2 deg rms phase error per chain
)doc")
        .def(py::init<radar_description::sptr>(), py::arg("radar"))
        .def("eq9_weights", &null_steering::eq9_weights, py::arg("main_lobe_rad"), py::arg("null_rad"),
             "The paper's eq. 9 (plane waves at the carrier).")
        .def("design", &null_steering::design, py::arg("main_lobe_rad"),
             py::arg("null_angles_rad") = std::vector<double>(), py::arg("null_receiver") = true)
        .def_property_readonly("main_lobe_halfwidth_rad", &null_steering::main_lobe_halfwidth_rad)
        .def("set_target_depth", &null_steering::set_target_depth, py::arg("depth_db"))
        .def_property_readonly("target_depth", &null_steering::target_depth)
        .def("coupling_db", &null_steering::coupling_db, py::arg("weights"))
        .def("expected_coupling_db", &null_steering::expected_coupling_db, py::arg("weights"),
             py::arg("phase_error_rad"))
        .def("beam_pattern_db", &null_steering::beam_pattern_db, py::arg("weights"),
             py::arg("angles_rad"), py::arg("frequencies_hz"),
             "Far-field gain (dB), rows: frequencies, columns: angles.")
        .def_property_readonly("receiver_bearing_rad", &null_steering::receiver_bearing_rad)
        .def("specular_bearing_rad", &null_steering::specular_bearing_rad, py::arg("standoff_m"));

    using block = null_steering_weights;
    py::class_<block, gr::sync_block, gr::block, gr::basic_block, std::shared_ptr<block>>(
        m, "null_steering_weights", R"doc(
TX weights for the sounder, as a "weights" message (dict: weights c32vector, main_lobe_deg,
null_angles_deg, null_receiver, coupling_db) at start and on every change, and the band-mean
far-field beam pattern (dB) as a float vector of num_angles.
)doc")
        .def(py::init(&block::make),
             py::arg("radar"),
             py::arg("main_lobe_deg") = 300.0,
             py::arg("null_receiver") = true,
             py::arg("null_angles_deg") = std::vector<double>(),
             py::arg("num_angles") = 360,
             py::arg("update_period_s") = 0.5)
        .def("set_main_lobe", &block::set_main_lobe, py::arg("main_lobe_deg"))
        .def("set_null_angles", &block::set_null_angles, py::arg("null_angles_deg"))
        .def("set_null_receiver", &block::set_null_receiver, py::arg("null_receiver"))
        .def("weights", &block::weights)
        .def("coupling_db", &block::coupling_db)
        .def("expected_coupling_db", &block::expected_coupling_db, py::arg("phase_error_deg"));
}
