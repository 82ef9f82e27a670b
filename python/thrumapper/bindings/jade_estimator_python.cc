/*
 * SPDX-License-Identifier: GPL-3.0-or-later
 */
/* Hand-written bindings: gr_modtool bind is not used (see tools/update_binding_hashes.py). */
/* BINDTOOL_GEN_AUTOMATIC(0) */
/* BINDTOOL_USE_PYGCCXML(0) */
/* BINDTOOL_HEADER_FILE(jade_estimator.h) */
/* BINDTOOL_HEADER_FILE_HASH(bab7433d01bdf096c64ed1fa4ca28783) */

#include <pybind11/complex.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

namespace py = pybind11;

#include <gnuradio/thrumapper/jade_estimator.h>

void bind_jade_estimator(py::module& m)
{
    using jade_estimator = gr::thrumapper::jade_estimator;

    py::class_<jade_estimator,
               gr::block,
               gr::basic_block,
               std::shared_ptr<jade_estimator>>(m, "jade_estimator", R"doc(
Joint angle-delay estimation (JADE) on every CSI frame.

In: one vector item per frame, M*N gr_complex, element-major (entry m*N + n).
Out: the MUSIC pseudo-spectrum, dB, num_angles*num_delays floats, angle-major.
Message port "paths": a dict per frame with frame_index, rx_time and pose when tagged,
model_order and paths (a vector of dicts angle_deg, delay_s, power, spectrum_db, stage);
with attach_csi also csi (the frame, c32vector), system_delay_s, tx_weights (when tagged) and
direct_path_cancelled, for wall_fusion's CSI fits.
Bad frames (NaN/Inf, all zeros) are logged, counted (num_skipped) and give no output.
)doc")
        .def(py::init(&jade_estimator::make),
             py::arg("radar"),
             py::arg("num_angles") = 360,
             py::arg("angle_min_deg") = 0.0,
             py::arg("angle_max_deg") = 360.0,
             py::arg("num_delays") = 200,
             py::arg("delay_min_s") = 0.0,
             py::arg("delay_max_s") = 40e-9,
             py::arg("max_paths") = 4,
             py::arg("smoothing_window") = 0,
             py::arg("system_delay_s") = 0.0,
             py::arg("stages") = 1,
             py::arg("attach_csi") = false)
        .def("set_angle_span", &jade_estimator::set_angle_span, py::arg("angle_min_deg"), py::arg("angle_max_deg"))
        .def("set_delay_span", &jade_estimator::set_delay_span, py::arg("delay_min_s"), py::arg("delay_max_s"))
        .def("set_max_paths", &jade_estimator::set_max_paths, py::arg("max_paths"))
        .def("set_smoothing_window", &jade_estimator::set_smoothing_window, py::arg("subcarriers"))
        .def("set_system_delay", &jade_estimator::set_system_delay, py::arg("system_delay_s"))
        .def("set_model_order", &jade_estimator::set_model_order, py::arg("order"))
        .def("set_stages", &jade_estimator::set_stages, py::arg("stages"))
        .def("stages", &jade_estimator::stages)
        .def("set_attach_csi", &jade_estimator::set_attach_csi, py::arg("attach_csi"))
        .def("attach_csi", &jade_estimator::attach_csi)
        .def("num_angles", &jade_estimator::num_angles)
        .def("num_delays", &jade_estimator::num_delays)
        .def("max_paths", &jade_estimator::max_paths)
        .def("smoothing_window", &jade_estimator::smoothing_window)
        .def("system_delay", &jade_estimator::system_delay)
        .def("num_skipped", &jade_estimator::num_skipped)
        .def("num_estimated", &jade_estimator::num_estimated);
}
