/*
 * SPDX-License-Identifier: GPL-3.0-or-later
 */
/* Hand-written bindings: gr_modtool bind is not used (see tools/update_binding_hashes.py). */
/* BINDTOOL_GEN_AUTOMATIC(0) */
/* BINDTOOL_USE_PYGCCXML(0) */
/* BINDTOOL_HEADER_FILE(ofdm_channel_estimator.h) */
/* BINDTOOL_HEADER_FILE_HASH(210e255509b9a068aff43326ab59326a) */

#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

namespace py = pybind11;

#include <gnuradio/thrumapper/ofdm_channel_estimator.h>

void bind_ofdm_channel_estimator(py::module& m)
{
    using est = gr::thrumapper::ofdm_channel_estimator;

    py::class_<est, gr::block, gr::basic_block, std::shared_ptr<est>>(
        m, "ofdm_channel_estimator", R"doc(
Frame timing from the preamble (joint over the M channels), CP removal, FFT and
least-squares CSI. In: M complex streams. Out: one M*N vector per frame (per TX element in
sequential mode), element-major (entry m*N + n), tagged frame_index, rx_time,
timing_offset, preamble_metric (and pose, rx_freq, frame_type as seen on input 0).
Frames with a missing or damaged preamble, or cut by an overflow, are skipped and counted.
)doc")
        .def(py::init(&est::make),
             py::arg("sounding"),
             py::arg("frame_offset") = 0,
             py::arg("search_window") = -1,
             py::arg("timing_backoff") = -1,
             py::arg("detection_threshold") = 0.3)
        .def("set_detection_threshold", &est::set_detection_threshold, py::arg("threshold"))
        .def("detection_threshold", &est::detection_threshold)
        .def("search_window", &est::search_window)
        .def("timing_backoff", &est::timing_backoff)
        .def("num_frames", &est::num_frames)
        .def("num_missing_preamble", &est::num_missing_preamble)
        .def("num_discontinuity_skips", &est::num_discontinuity_skips)
        .def("num_discontinuities", &est::num_discontinuities);
}
