/*
 * SPDX-License-Identifier: GPL-3.0-or-later
 */
/* Hand-written bindings: gr_modtool bind is not used (see tools/update_binding_hashes.py). */
/* BINDTOOL_GEN_AUTOMATIC(0) */
/* BINDTOOL_USE_PYGCCXML(0) */
/* BINDTOOL_HEADER_FILE(ofdm_sounding.h) */
/* BINDTOOL_HEADER_FILE_HASH(ba62245446e709e00b9f25e4f96f213a) */

#include <pybind11/complex.h>
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

namespace py = pybind11;

#include <gnuradio/thrumapper/ofdm_sounding.h>

namespace {
using cvec = py::array_t<gr_complex, py::array::c_style | py::array::forcecast>;

std::vector<const gr_complex*> rows(const cvec& samples, int min_len, const char* what)
{
    if (samples.ndim() != 2)
        throw std::invalid_argument(std::string(what) + ": expected an (M, L) complex array");
    if (samples.shape(1) < min_len)
        throw std::invalid_argument(std::string(what) + ": expected at least " +
                                    std::to_string(min_len) + " samples per channel, got " +
                                    std::to_string(samples.shape(1)));
    std::vector<const gr_complex*> p(samples.shape(0));
    for (size_t m = 0; m < p.size(); m++)
        p[m] = samples.data(m, 0);
    return p;
}
} // namespace

void bind_ofdm_sounding(py::module& m)
{
    using gr::thrumapper::ofdm_demodulator;
    using gr::thrumapper::ofdm_sounding;
    using gr::thrumapper::sounding_mode;

    py::enum_<sounding_mode>(m, "sounding_mode", "How the TX elements share a sounding frame.")
        .value("weighted", sounding_mode::weighted)
        .value("sequential", sounding_mode::sequential)
        .value("interleaved", sounding_mode::interleaved)
        .export_values();

    py::class_<ofdm_sounding, std::shared_ptr<ofdm_sounding>>(m, "ofdm_sounding", R"doc(
The OFDM sounding waveform (docs/radio-chain.md): frame layout, preamble, pilots.

Frame: preamble | slot 0 ... slot S-1 | gap; slot = cyclic prefix (cp_len) + num_symbols
periods of the pilot symbol (fft_len) + cyclic postfix (cp_len). S = 1, or K in sequential
mode. Subcarrier n is FFT bin (offset_n - tuning_offset_hz) / (sample_rate_hz / fft_len):
the default 120 MS/s, FFT 256 puts a 128-subcarrier 120 MHz radar on the odd bins.

Example:
    radar = thrumapper.radar_description.make_uca_pair()
    sounding = thrumapper.ofdm_sounding.make(radar, 120e6, 256, 64, 4, 128, 64)
)doc")
        .def_static("make",
                    &ofdm_sounding::make,
                    py::arg("radar"),
                    py::arg("sample_rate_hz") = 120e6,
                    py::arg("fft_len") = 256,
                    py::arg("cp_len") = 64,
                    py::arg("num_symbols") = 4,
                    py::arg("preamble_len") = 128,
                    py::arg("gap_len") = 64,
                    py::arg("mode") = sounding_mode::weighted,
                    py::arg("tuning_offset_hz") = 0.0)
        .def_property_readonly("radar", &ofdm_sounding::radar)
        .def_property_readonly("sample_rate_hz", &ofdm_sounding::sample_rate_hz)
        .def_property_readonly("bin_spacing_hz", &ofdm_sounding::bin_spacing_hz)
        .def_property_readonly("tuning_offset_hz", &ofdm_sounding::tuning_offset_hz)
        .def_property_readonly("lo_frequency_hz", &ofdm_sounding::lo_frequency_hz)
        .def_property_readonly("fft_len", &ofdm_sounding::fft_len)
        .def_property_readonly("cp_len", &ofdm_sounding::cp_len)
        .def_property_readonly("num_symbols", &ofdm_sounding::num_symbols)
        .def_property_readonly("preamble_len", &ofdm_sounding::preamble_len)
        .def_property_readonly("gap_len", &ofdm_sounding::gap_len)
        .def_property_readonly("mode", &ofdm_sounding::mode)
        .def_property_readonly("num_tx", &ofdm_sounding::num_tx)
        .def_property_readonly("num_rx", &ofdm_sounding::num_rx)
        .def_property_readonly("num_subcarriers", &ofdm_sounding::num_subcarriers)
        .def_property_readonly("num_slots", &ofdm_sounding::num_slots)
        .def_property_readonly("items_per_frame", &ofdm_sounding::items_per_frame)
        .def_property_readonly("slot_len", &ofdm_sounding::slot_len)
        .def_property_readonly("burst_len", &ofdm_sounding::burst_len)
        .def_property_readonly("frame_len", &ofdm_sounding::frame_len)
        .def_property_readonly("frame_duration_s", &ofdm_sounding::frame_duration_s)
        .def("slot_start", &ofdm_sounding::slot_start, py::arg("slot"))
        .def("window_start", &ofdm_sounding::window_start, py::arg("slot"), py::arg("symbol"))
        .def_property_readonly("subcarrier_bins", &ofdm_sounding::subcarrier_bins)
        .def_property_readonly("subcarrier_signed_bins", &ofdm_sounding::subcarrier_signed_bins)
        .def("bin_frequency_hz", &ofdm_sounding::bin_frequency_hz, py::arg("bin"))
        .def_property_readonly("pilots", &ofdm_sounding::pilots)
        .def_property_readonly("preamble", &ofdm_sounding::preamble)
        .def("tx_element_of_subcarrier", &ofdm_sounding::tx_element_of_subcarrier, py::arg("n"))
        .def(
            "frame",
            [](const ofdm_sounding& s, const std::vector<gr_complex>& weights) {
                py::array_t<gr_complex> out({ s.num_tx(), s.frame_len() });
                for (int k = 0; k < s.num_tx(); k++)
                    s.frame_samples(k, weights, out.mutable_data(k, 0));
                return out;
            },
            py::arg("weights") = std::vector<gr_complex>(),
            "One frame of every TX element, a (K, frame_len) complex64 array.")
        .def("to_string", &ofdm_sounding::to_string)
        .def("__repr__", &ofdm_sounding::to_string);

    py::class_<ofdm_demodulator::detection>(m, "ofdm_detection")
        .def_readonly("found", &ofdm_demodulator::detection::found)
        .def_readonly("offset", &ofdm_demodulator::detection::offset)
        .def_readonly("metric", &ofdm_demodulator::detection::metric);

    py::class_<ofdm_demodulator, std::shared_ptr<ofdm_demodulator>>(m, "ofdm_demodulator", R"doc(
Frame timing and least-squares CSI for one ofdm_sounding (the estimator block's core).
Arrays are (M, L) complex64, starting search_window samples before the nominal frame start.
)doc")
        .def(py::init<gr::thrumapper::ofdm_sounding::sptr, int, int, double>(),
             py::arg("sounding"),
             py::arg("search_window"),
             py::arg("timing_backoff"),
             py::arg("detection_threshold"))
        .def("span", &ofdm_demodulator::span)
        .def(
            "detect",
            [](ofdm_demodulator& d, const cvec& samples) {
                auto p = rows(samples, d.span(), "detect");
                return d.detect(p.data(), int(p.size()));
            },
            py::arg("samples"))
        .def(
            "estimate",
            [](ofdm_demodulator& d, const cvec& samples, int offset, double fractional) {
                auto p = rows(samples, d.span(), "estimate");
                const auto& s = *d.sounding();
                py::array_t<gr_complex> out(
                    { s.items_per_frame(), int(p.size()), s.num_subcarriers() });
                d.estimate(p.data(), int(p.size()), offset, fractional, out.mutable_data());
                return out;
            },
            py::arg("samples"),
            py::arg("offset"),
            py::arg("fractional_offset_samples") = 0.0,
            "The CSI of every slot, (items_per_frame, M, N) complex64.");
}
