/*
 * SPDX-License-Identifier: GPL-3.0-or-later
 */
/* Hand-written bindings: gr_modtool bind is not used (see tools/update_binding_hashes.py). */
/* BINDTOOL_GEN_AUTOMATIC(0) */
/* BINDTOOL_USE_PYGCCXML(0) */
/* BINDTOOL_HEADER_FILE(radar_description.h) */
/* BINDTOOL_HEADER_FILE_HASH(c2d2b5cce1c93f91062626733afa1f7b) */

#include <pybind11/complex.h>
#include <pybind11/eigen.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

namespace py = pybind11;

#include <gnuradio/thrumapper/radar_description.h>

void bind_radar_description(py::module& m)
{
    using rd = gr::thrumapper::radar_description;
    m.attr("speed_of_light_m_s") = gr::thrumapper::speed_of_light_m_s;

    py::class_<rd, std::shared_ptr<rd>>(m, "radar_description", R"doc(
The one description of the bistatic radar that every block takes.

TX and RX element positions in the robot frame (metres; +x forward, +y left), the carrier,
the used subcarrier offsets and the default TX weights. Immutable; share one object, made in
a GRC variable block, between all blocks (like digital.constellation).

Example:
    radar = thrumapper.radar_description.make_uca_pair(elements=8, radius_m=0.08,
                                                       baseline_m=0.7, carrier_hz=2.44e9,
                                                       bandwidth_hz=120e6, subcarriers=128)
)doc")
        .def_static("make",
                    &rd::make,
                    py::arg("tx_elements_m"),
                    py::arg("rx_elements_m"),
                    py::arg("carrier_hz"),
                    py::arg("subcarrier_offsets_hz"),
                    py::arg("tx_weights") = std::vector<gr_complex>(),
                    "A radar from explicit K×2 TX and M×2 RX element positions (robot frame, m).")
        .def_static("make_uca_pair",
                    &rd::make_uca_pair,
                    py::arg("elements") = 8,
                    py::arg("radius_m") = 0.08,
                    py::arg("baseline_m") = 0.7,
                    py::arg("carrier_hz") = 2.44e9,
                    py::arg("bandwidth_hz") = 120e6,
                    py::arg("subcarriers") = 128,
                    py::arg("rotation_rad") = 0.0,
                    "Two equal UCAs on the robot's x axis: TX centred at (-baseline/2, 0), RX at "
                    "(+baseline/2, 0); N subcarriers uniform over the bandwidth.")
        .def_static("uca_positions",
                    &rd::uca_positions,
                    py::arg("count"),
                    py::arg("radius_m"),
                    py::arg("rotation_rad") = 0.0,
                    py::arg("centre_x_m") = 0.0,
                    py::arg("centre_y_m") = 0.0,
                    "count×2 positions of a uniform circular array, element i at rotation+2πi/count.")
        .def_static("ula_positions",
                    &rd::ula_positions,
                    py::arg("count"),
                    py::arg("spacing_m"),
                    py::arg("axis_rad") = 0.0,
                    py::arg("centre_x_m") = 0.0,
                    py::arg("centre_y_m") = 0.0,
                    "count×2 positions of a centred uniform linear array along axis_rad.")
        .def_static("uniform_subcarriers",
                    &rd::uniform_subcarriers,
                    py::arg("count"),
                    py::arg("bandwidth_hz"),
                    "count offsets spaced bandwidth/count, centred on zero, ascending.")
        .def_property_readonly("tx_elements_m", &rd::tx_elements_m)
        .def_property_readonly("rx_elements_m", &rd::rx_elements_m)
        .def_property_readonly("tx_centre_m", &rd::tx_centre_m)
        .def_property_readonly("rx_centre_m", &rd::rx_centre_m)
        .def_property_readonly("carrier_hz", &rd::carrier_hz)
        .def_property_readonly("subcarrier_offsets_hz", &rd::subcarrier_offsets_hz)
        .def_property_readonly("tx_weights", &rd::tx_weights)
        .def_property_readonly("num_tx", &rd::num_tx)
        .def_property_readonly("num_rx", &rd::num_rx)
        .def_property_readonly("num_subcarriers", &rd::num_subcarriers)
        .def_property_readonly("uniform_spacing", &rd::uniform_spacing)
        .def_property_readonly("subcarrier_spacing_hz", &rd::subcarrier_spacing_hz)
        .def_property_readonly("baseline_m", &rd::baseline_m)
        .def_property_readonly("direct_delay_s", &rd::direct_delay_s)
        .def_property_readonly("direct_aoa_rad", &rd::direct_aoa_rad)
        .def("to_string", &rd::to_string)
        .def("__repr__", &rd::to_string);
}
