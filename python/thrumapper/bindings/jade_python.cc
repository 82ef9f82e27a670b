/*
 * SPDX-License-Identifier: GPL-3.0-or-later
 */
/* Hand-written bindings: gr_modtool bind is not used (see tools/update_binding_hashes.py). */
/* BINDTOOL_GEN_AUTOMATIC(0) */
/* BINDTOOL_USE_PYGCCXML(0) */
/* BINDTOOL_HEADER_FILE(jade.h) */
/* BINDTOOL_HEADER_FILE_HASH(e97580dd912d391529e24891ff62cf07) */

#include <pybind11/complex.h>
#include <pybind11/eigen.h>
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

namespace py = pybind11;

#include <gnuradio/thrumapper/jade.h>
#include <cmath>

namespace {
// (M, N) or (F, M, N) complex array -> (F·M) × N matrix, frame-major rows.
Eigen::MatrixXcd frames_from_array(const gr::thrumapper::jade& j,
                                   py::array_t<std::complex<double>, py::array::c_style | py::array::forcecast> a)
{
    const int M = j.radar()->num_rx(), N = j.radar()->num_subcarriers();
    if (a.ndim() != 2 && a.ndim() != 3)
        throw std::invalid_argument("jade: expected CSI of shape (M, N) or (F, M, N), got " +
                                    std::to_string(a.ndim()) + " dimensions");
    const int F = a.ndim() == 3 ? a.shape(0) : 1;
    const int am = a.shape(a.ndim() - 2), an = a.shape(a.ndim() - 1);
    if (am != M || an != N || F < 1)
        throw std::invalid_argument("jade: expected CSI frames of shape (M, N) = (" +
                                    std::to_string(M) + ", " + std::to_string(N) + "), got (" +
                                    std::to_string(am) + ", " + std::to_string(an) + ")");
    Eigen::Map<const Eigen::Matrix<std::complex<double>, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>>
        map(a.data(), F * M, N);
    return map;
}
} // namespace

void bind_jade(py::module& m)
{
    using namespace gr::thrumapper;
    py::class_<jade_path>(m, "jade_path", "One path found by JADE.")
        .def(py::init<>())
        .def_readwrite("aoa_rad", &jade_path::aoa_rad)
        .def_readwrite("delay_s", &jade_path::delay_s)
        .def_readwrite("power", &jade_path::power)
        .def_readwrite("amplitude", &jade_path::amplitude)
        .def_readwrite("spectrum_db", &jade_path::spectrum_db)
        .def_readwrite("stage", &jade_path::stage)
        .def_property_readonly("aoa_deg",
                               [](const jade_path& p) { return p.aoa_rad * 180.0 / M_PI; })
        .def("as_dict",
             [](const jade_path& p) {
                 py::dict d;
                 d["aoa_deg"] = p.aoa_rad * 180.0 / M_PI;
                 d["delay_s"] = p.delay_s;
                 d["power"] = p.power;
                 d["spectrum_db"] = p.spectrum_db;
                 d["stage"] = p.stage;
                 return d;
             })
        .def("__repr__", [](const jade_path& p) {
            char buf[160];
            std::snprintf(buf,
                          sizeof buf,
                          "jade_path(aoa_deg=%.3f, delay_s=%.4e, power=%.3e, stage=%d)",
                          p.aoa_rad * 180.0 / M_PI,
                          p.delay_s,
                          p.power,
                          p.stage);
            return std::string(buf);
        });

    py::class_<jade>(m, "jade", R"doc(
JADE joint angle-delay estimator (paper eq. 5-8), the C++ core of jade_estimator.

    est = thrumapper.jade(radar, thrumapper.jade.full_circle_grid(360),
                          thrumapper.jade.linear_grid(0, 40e-9, 200), smoothing_window=0,
                          max_paths=4)
    paths = est.estimate(csi)      # csi: (M, N) or (F, M, N) complex, F frames of one pose
    surface_db = est.spectrum_db   # angles x delays
)doc")
        .def(py::init<radar_description::sptr, const std::vector<double>&, const std::vector<double>&, int, int>(),
             py::arg("radar"),
             py::arg("angles_rad"),
             py::arg("delays_s"),
             py::arg("smoothing_window") = 0,
             py::arg("max_paths") = 4)
        .def_static("full_circle_grid", &jade::full_circle_grid, py::arg("count"))
        .def_static("linear_grid", &jade::linear_grid, py::arg("start"), py::arg("stop"), py::arg("count"))
        .def("set_angle_grid", &jade::set_angle_grid, py::arg("angles_rad"))
        .def("set_delay_grid", &jade::set_delay_grid, py::arg("delays_s"))
        .def("set_smoothing_window", &jade::set_smoothing_window, py::arg("subcarriers"))
        .def("set_max_paths", &jade::set_max_paths, py::arg("max_paths"))
        .def("set_model_order", &jade::set_model_order, py::arg("order"))
        .def("set_order_threshold", &jade::set_order_threshold, py::arg("factor"))
        .def("set_system_delay", &jade::set_system_delay, py::arg("system_delay_s"))
        .def("set_refine", &jade::set_refine, py::arg("refine"))
        .def("set_stages", &jade::set_stages, py::arg("stages"),
             "Successive cancellation: estimate, cancel the strongest return, estimate again.")
        .def_property_readonly("stages", &jade::stages)
        .def_property_readonly("angle_grid", &jade::angle_grid)
        .def_property_readonly("delay_grid", &jade::delay_grid)
        .def_property_readonly("smoothing_window", &jade::smoothing_window)
        .def_property_readonly("max_paths", &jade::max_paths)
        .def_property_readonly("system_delay", &jade::system_delay)
        .def_property_readonly("order_threshold", &jade::order_threshold)
        .def_property_readonly("radar", &jade::radar)
        .def(
            "estimate",
            [](jade& j, py::array_t<std::complex<double>, py::array::c_style | py::array::forcecast> csi) {
                Eigen::MatrixXcd frames = frames_from_array(j, csi);
                py::gil_scoped_release release;
                return j.estimate_matrix(frames);
            },
            py::arg("csi"),
            "Paths in CSI of shape (M, N) or (F, M, N) (F frames of one pose), strongest first.")
        .def_property_readonly("spectrum_db", &jade::spectrum_db, "Last spectrum, dB, angles × delays.")
        .def_property_readonly("eigenvalues", &jade::eigenvalues,
                               "Leading eigenvalues of the last estimate, descending.")
        .def_property_readonly("noise_eigenvalue", &jade::noise_eigenvalue,
                               "Median eigenvalue of the last estimate (the noise level).")
        .def_property_readonly("model_order", &jade::model_order)
        .def_property_readonly("signal_subspace", &jade::signal_subspace)
        .def("subspace_fit", &jade::subspace_fit, py::arg("aoa_rad"), py::arg("delay_s"))
        .def_static(
            "smooth",
            [](py::array_t<std::complex<double>, py::array::c_style | py::array::forcecast> csi, int window) {
                if (csi.ndim() != 2 && csi.ndim() != 3)
                    throw std::invalid_argument("smooth: expected (M, N) or (F, M, N)");
                const int F = csi.ndim() == 3 ? csi.shape(0) : 1;
                const int M = csi.shape(csi.ndim() - 2), N = csi.shape(csi.ndim() - 1);
                Eigen::Map<const Eigen::Matrix<std::complex<double>, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>>
                    map(csi.data(), F * M, N);
                return jade::smooth(map, M, window);
            },
            py::arg("csi"),
            py::arg("window"),
            "Smoothed data (eq. 6-7): (M·L) × (F·(N-L+1)).");
}
