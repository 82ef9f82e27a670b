/*
 * SPDX-License-Identifier: GPL-3.0-or-later
 */
/* Hand-written bindings: gr_modtool bind is not used (see tools/update_binding_hashes.py). */
/* BINDTOOL_GEN_AUTOMATIC(0) */
/* BINDTOOL_USE_PYGCCXML(0) */
/* BINDTOOL_HEADER_FILE(manifold.h) */
/* BINDTOOL_HEADER_FILE_HASH(650b624fbe94010d7eac924e9d6deabe) */

#include <pybind11/complex.h>
#include <pybind11/eigen.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

namespace py = pybind11;

#include <gnuradio/thrumapper/manifold.h>

void bind_manifold(py::module& m)
{
    using namespace gr::thrumapper;
    m.def("steering_far_field",
          &steering_far_field,
          py::arg("elements_m"),
          py::arg("aoa_rad"),
          py::arg("freq_hz"),
          "Plane-wave steering vector a_m = exp(+j2πf p_m·u(θ)/c), p_m relative to the array centre.");
    m.def("steering_near_field",
          &steering_near_field,
          py::arg("elements_m"),
          py::arg("source_m"),
          py::arg("freq_hz"),
          "Spherical-wavefront steering vector toward a point source, phase-referenced to the "
          "array centre: (d0/d_m) exp(-j2πf (d_m - d0)/c).");
    m.def("delay_manifold",
          &delay_manifold,
          py::arg("subcarrier_offsets_hz"),
          py::arg("delay_s"),
          "g_n(τ) = exp(-j2π Δf_n τ).");
    m.def("space_time_manifold",
          &space_time_manifold,
          py::arg("radar"),
          py::arg("aoa_rad"),
          py::arg("delay_s"),
          "u(θ, τ) = a(θ) ⊗ g(τ), far field at the carrier, element-major (entry m·N + n).");
    m.def("direct_path_response",
          &direct_path_response,
          py::arg("radar"),
          py::arg("tx_weights") = std::vector<gr_complex>(),
          py::arg("system_delay_s") = 0.0,
          "Exact wideband near-field direct TX→RX coupling, M·N element-major.");
}
