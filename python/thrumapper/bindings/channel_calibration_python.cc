/*
 * SPDX-License-Identifier: GPL-3.0-or-later
 */
/* Hand-written bindings: gr_modtool bind is not used (see tools/update_binding_hashes.py). */
/* BINDTOOL_GEN_AUTOMATIC(0) */
/* BINDTOOL_USE_PYGCCXML(0) */
/* BINDTOOL_HEADER_FILE(channel_calibration.h) */
/* BINDTOOL_HEADER_FILE_HASH(658e3e65ab3a0a369650bd739142b4b2) */

#include <pybind11/complex.h>
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

namespace py = pybind11;

#include <gnuradio/thrumapper/channel_calibration.h>

void bind_channel_calibration(py::module& m)
{
    using gr::thrumapper::calibration_coefficients;
    using gr::thrumapper::channel_calibration;
    using gr::thrumapper::channel_corrector;
    using cvec = py::array_t<gr_complex, py::array::c_style | py::array::forcecast>;

    py::class_<calibration_coefficients>(m, "calibration_coefficients", R"doc(
Per-channel RX chain corrections: dc (complex), gain_db, phase_rad (at the LO), delay_s,
relative to reference_channel (-1: the mean). chain_response(m, f) is the modelled chain
10^(gain_db/20)·e^{j·phase_rad}·e^{-j2π f delay_s} at baseband frequency f; the correction
divides by it after removing dc. Saved and loaded as JSON (docs/radio-chain.md).
)doc")
        .def(py::init<>())
        .def_static("identity", &calibration_coefficients::identity, py::arg("num_channels"))
        .def_readwrite("dc", &calibration_coefficients::dc)
        .def_readwrite("gain_db", &calibration_coefficients::gain_db)
        .def_readwrite("phase_rad", &calibration_coefficients::phase_rad)
        .def_readwrite("delay_s", &calibration_coefficients::delay_s)
        .def_readwrite("reference_channel", &calibration_coefficients::reference_channel)
        .def_readwrite("source", &calibration_coefficients::source)
        .def_readwrite("center_frequency_hz", &calibration_coefficients::center_frequency_hz)
        .def_readwrite("sample_rate_hz", &calibration_coefficients::sample_rate_hz)
        .def("num_channels", &calibration_coefficients::num_channels)
        .def("validate", &calibration_coefficients::validate)
        .def("chain_response",
             &calibration_coefficients::chain_response,
             py::arg("channel"),
             py::arg("baseband_hz"))
        .def("to_json", &calibration_coefficients::to_json)
        .def_static("from_json", &calibration_coefficients::from_json, py::arg("text"))
        .def("save", &calibration_coefficients::save, py::arg("path"))
        .def_static("load", &calibration_coefficients::load, py::arg("path"));

    py::class_<channel_calibration, std::shared_ptr<channel_calibration>>(
        m, "channel_calibration", R"doc(
Estimates the RX chains' DC offset, gain, phase and delay from an (M, L) segment that
received one common signal: a split reference (source "reference") or the sounder's direct
path (source "direct_path").
)doc")
        .def(py::init<gr::thrumapper::ofdm_sounding::sptr,
                      const std::string&,
                      int,
                      const std::vector<gr_complex>&>(),
             py::arg("sounding"),
             py::arg("source") = "reference",
             py::arg("reference_channel") = 0,
             py::arg("tx_weights") = std::vector<gr_complex>())
        .def(
            "estimate",
            [](channel_calibration& c, const cvec& samples, double center_frequency_hz) {
                if (samples.ndim() != 2)
                    throw std::invalid_argument("estimate: expected an (M, L) complex array");
                std::vector<const gr_complex*> p(samples.shape(0));
                for (size_t m = 0; m < p.size(); m++)
                    p[m] = samples.data(m, 0);
                return c.estimate(
                    p.data(), int(p.size()), int(samples.shape(1)), center_frequency_hz);
            },
            py::arg("samples"),
            py::arg("center_frequency_hz") = 0.0)
        .def_property_readonly("source", &channel_calibration::source)
        .def_property_readonly("reference_channel", &channel_calibration::reference_channel);

    py::class_<channel_corrector, std::shared_ptr<channel_corrector>>(m, "channel_corrector", R"doc(
Applies calibration_coefficients to M streams (the calibrator block's core): process takes
(M, n + taps - 1) samples and returns (M, n); output i is input i + taps - 1 - lookahead.
)doc")
        .def(py::init<int, int, double>(),
             py::arg("num_channels"),
             py::arg("fft_len"),
             py::arg("sample_rate_hz"))
        .def("set_coefficients", &channel_corrector::set_coefficients, py::arg("coefficients"))
        .def("coefficients", &channel_corrector::coefficients)
        .def("taps", &channel_corrector::taps)
        .def("lookahead", &channel_corrector::lookahead)
        .def(
            "process",
            [](channel_corrector& c, const cvec& samples) {
                if (samples.ndim() != 2 || samples.shape(1) < c.taps())
                    throw std::invalid_argument("process: expected (M, n + taps - 1) samples");
                const int n = int(samples.shape(1)) - (c.taps() - 1);
                py::array_t<gr_complex> out({ int(samples.shape(0)), n });
                for (int m = 0; m < samples.shape(0); m++)
                    c.process(m, samples.data(m, 0), out.mutable_data(m, 0), n);
                return out;
            },
            py::arg("samples"));
}
