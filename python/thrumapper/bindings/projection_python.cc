/*
 * SPDX-License-Identifier: GPL-3.0-or-later
 */
/* Hand-written bindings: gr_modtool bind is not used (see tools/update_binding_hashes.py). */
/* BINDTOOL_GEN_AUTOMATIC(0) */
/* BINDTOOL_USE_PYGCCXML(0) */
/* BINDTOOL_HEADER_FILE(projection.h) */
/* BINDTOOL_HEADER_FILE_HASH(3ac384db8ab51fe1ef611c7598ed8f15) */

#include <pybind11/complex.h>
#include <pybind11/eigen.h>
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

namespace py = pybind11;

#include <gnuradio/thrumapper/projection.h>
#include <gnuradio/thrumapper/projection_canceller.h>

void bind_projection(py::module& m)
{
    using namespace gr::thrumapper;
    py::class_<path_projector>(m, "path_projector", R"doc(
Cancels known paths from CSI frames by projection (eq. 10), on whole M*N frames.

    proj = thrumapper.path_projector(radar)
    proj.set_system_delay(20e-9)
    proj.set_paths([math.radians(243.4)], [5.22e-9])
    proj.set_direct_path(True, weights)
    clean = proj.apply(csi)          # (M, N) or (F, M, N)
)doc")
        .def(py::init<radar_description::sptr>(), py::arg("radar"))
        .def("set_system_delay", &path_projector::set_system_delay, py::arg("system_delay_s"))
        .def("set_paths", &path_projector::set_paths, py::arg("aoa_rad"), py::arg("delay_s"))
        .def("set_direct_path", &path_projector::set_direct_path, py::arg("cancel"),
             py::arg("tx_weights") = std::vector<gr_complex>())
        .def("clear", &path_projector::clear)
        .def_property_readonly("rank", &path_projector::rank)
        .def_property_readonly("basis", &path_projector::basis)
        .def("projector", &path_projector::projector)
        .def(
            "apply",
            [](const path_projector& p,
               py::array_t<std::complex<double>, py::array::c_style | py::array::forcecast> csi) {
                if (csi.ndim() != 2 && csi.ndim() != 3)
                    throw std::invalid_argument("path_projector: expected (M, N) or (F, M, N)");
                const int F = csi.ndim() == 3 ? csi.shape(0) : 1;
                const int M = csi.shape(csi.ndim() - 2), N = csi.shape(csi.ndim() - 1);
                Eigen::Map<const Eigen::Matrix<std::complex<double>, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>>
                    map(csi.data(), F * M, N);
                Eigen::Matrix<std::complex<double>, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor> out =
                    p.apply_matrix(map);
                py::array_t<std::complex<double>> result(std::vector<ssize_t>(csi.shape(), csi.shape() + csi.ndim()));
                std::copy(out.data(), out.data() + out.size(), result.mutable_data());
                return result;
            },
            py::arg("csi"));

    using block = projection_canceller;
    py::class_<block, gr::block, gr::basic_block, std::shared_ptr<block>>(m, "projection_canceller", R"doc(
Removes known paths (far-field angle/delay pairs, and the near-field direct path) from CSI
frames by projection. Message ports: "paths" (jade_estimator's paths message, or a dict with
"paths" or "clear"), "weights" (null_steering_weights' message, or a c32vector).
)doc")
        .def(py::init(&block::make),
             py::arg("radar"),
             py::arg("aoa_deg") = std::vector<double>(),
             py::arg("delay_s") = std::vector<double>(),
             py::arg("cancel_direct") = false,
             py::arg("system_delay_s") = 0.0)
        .def("set_paths", &block::set_paths, py::arg("aoa_deg"), py::arg("delay_s"))
        .def("set_cancel_direct", &block::set_cancel_direct, py::arg("cancel_direct"))
        .def("set_system_delay", &block::set_system_delay, py::arg("system_delay_s"))
        .def("set_tx_weights", &block::set_tx_weights, py::arg("weights"))
        .def("rank", &block::rank)
        .def("num_skipped", &block::num_skipped)
        .def("num_bad_messages", &block::num_bad_messages);
}
