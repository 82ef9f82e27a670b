/*
 * SPDX-License-Identifier: GPL-3.0-or-later
 */
/* Hand-written bindings: gr_modtool bind is not used (see tools/update_binding_hashes.py). */
/* BINDTOOL_GEN_AUTOMATIC(0) */
/* BINDTOOL_USE_PYGCCXML(0) */
/* BINDTOOL_HEADER_FILE(channel_calibrator.h) */
/* BINDTOOL_HEADER_FILE_HASH(c8061e8ab6add8a22de34a591097371d) */

#include <pybind11/complex.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

namespace py = pybind11;

#include <gnuradio/thrumapper/channel_calibrator.h>

void bind_channel_calibrator(py::module& m)
{
    using cal = gr::thrumapper::channel_calibrator;

    py::class_<cal, gr::block, gr::basic_block, std::shared_ptr<cal>>(m, "channel_calibrator", R"doc(
Multichannel RX calibration (paper §3.3): DC offset removal, amplitude equalisation, phase
and delay alignment of M streams. Estimated from calibration_len samples of a split
reference (source "reference") or the direct path ("direct_path") at start, after a
retune (rx_freq tag) and on a "calibrate" message; applied at the next frame boundary;
published on "coefficients" and saved to / loaded from coefficients_path (JSON).
)doc")
        .def(py::init(&cal::make),
             py::arg("sounding"),
             py::arg("source") = "reference",
             py::arg("calibration_len") = 0,
             py::arg("reference_channel") = 0,
             py::arg("calibrate_at_start") = true,
             py::arg("coefficients_path") = "",
             py::arg("frame_offset") = 0)
        .def("calibrate", &cal::calibrate)
        .def("set_coefficients", &cal::set_coefficients, py::arg("coefficients"))
        .def("coefficients", &cal::coefficients)
        .def("save_coefficients", &cal::save_coefficients, py::arg("path"))
        .def("load_coefficients", &cal::load_coefficients, py::arg("path"))
        .def("num_calibrations", &cal::num_calibrations)
        .def("num_failed_calibrations", &cal::num_failed_calibrations)
        .def("calibration_pending", &cal::calibration_pending)
        .def("calibration_len", &cal::calibration_len);
}
