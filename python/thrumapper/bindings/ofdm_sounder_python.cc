/*
 * SPDX-License-Identifier: GPL-3.0-or-later
 */
/* Hand-written bindings: gr_modtool bind is not used (see tools/update_binding_hashes.py). */
/* BINDTOOL_GEN_AUTOMATIC(0) */
/* BINDTOOL_USE_PYGCCXML(0) */
/* BINDTOOL_HEADER_FILE(ofdm_sounder.h) */
/* BINDTOOL_HEADER_FILE_HASH(a4fda49e089350ceb259ecee6ee0ae86) */

#include <pybind11/complex.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

namespace py = pybind11;

#include <gnuradio/thrumapper/ofdm_sounder.h>

void bind_ofdm_sounder(py::module& m)
{
    using ofdm_sounder = gr::thrumapper::ofdm_sounder;

    py::class_<ofdm_sounder,
               gr::sync_block,
               gr::block,
               gr::basic_block,
               std::shared_ptr<ofdm_sounder>>(m, "ofdm_sounder", R"doc(
OFDM sounding bursts, one output stream per TX element, frame after frame.

Weighted mode: element k sends the frame times w_k. Tags on every output: tx_sob / tx_eob
(each frame is one burst), tx_time when start_time_s >= 0, frame_index, and tx_weights when
they change. Message port "weights": a dict {"weights": c32vector/c64vector of K} or a bare
complex vector; applied at the next frame, malformed ones logged and counted.
)doc")
        .def(py::init(&ofdm_sounder::make),
             py::arg("sounding"),
             py::arg("weights") = std::vector<gr_complex>(),
             py::arg("start_time_s") = -1.0)
        .def("set_weights", &ofdm_sounder::set_weights, py::arg("weights"))
        .def("weights", &ofdm_sounder::weights)
        .def("num_frames", &ofdm_sounder::num_frames)
        .def("num_rejected_weights", &ofdm_sounder::num_rejected_weights);
}
