/* -*- c++ -*- */
/*
 * SPDX-License-Identifier: GPL-3.0-or-later
 */
#include <gnuradio/thrumapper/channel_calibration.h>
#include <boost/property_tree/json_parser.hpp>
#include <boost/property_tree/ptree.hpp>
#include <volk/volk.h>
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <sstream>
#include <stdexcept>

namespace gr {
namespace thrumapper {

namespace {
int next_pow2(int n)
{
    int p = 1;
    while (p < n)
        p <<= 1;
    return p;
}

std::string number(double v)
{
    if (!std::isfinite(v))
        throw std::invalid_argument("calibration: non-finite value cannot be written to JSON");
    char buf[64];
    std::snprintf(buf, sizeof(buf), "%.17g", v);
    return buf;
}

std::string quoted(const std::string& s)
{
    std::string out = "\"";
    for (char c : s) {
        if (c == '"' || c == '\\')
            out += '\\';
        out += c;
    }
    return out + "\"";
}

double to_double(const boost::property_tree::ptree& node, const std::string& field)
{
    try {
        return std::stod(node.get_value<std::string>());
    } catch (const std::exception&) {
        throw std::invalid_argument("calibration JSON: " + field + ": expected a number, got '" +
                                    node.get_value<std::string>() + "'");
    }
}

const boost::property_tree::ptree& child(const boost::property_tree::ptree& node,
                                         const std::string& key,
                                         const std::string& where)
{
    auto it = node.find(key);
    if (it == node.not_found())
        throw std::invalid_argument("calibration JSON: " + where + key + ": missing");
    return it->second;
}
} // namespace

// ---------------------------------------------------------------------------------------
// Coefficients
// ---------------------------------------------------------------------------------------
calibration_coefficients calibration_coefficients::identity(int num_channels)
{
    if (num_channels < 1)
        throw std::invalid_argument("calibration: num_channels must be at least 1");
    calibration_coefficients c;
    c.dc.assign(num_channels, gr_complex(0, 0));
    c.gain_db.assign(num_channels, 0.0);
    c.phase_rad.assign(num_channels, 0.0);
    c.delay_s.assign(num_channels, 0.0);
    return c;
}

void calibration_coefficients::validate() const
{
    const size_t m = gain_db.size();
    if (m == 0)
        throw std::invalid_argument("calibration: gain_db: no channels");
    if (dc.size() != m)
        throw std::invalid_argument("calibration: dc: expected " + std::to_string(m) +
                                    " values, got " + std::to_string(dc.size()));
    if (phase_rad.size() != m)
        throw std::invalid_argument("calibration: phase_rad: expected " + std::to_string(m) +
                                    " values, got " + std::to_string(phase_rad.size()));
    if (delay_s.size() != m)
        throw std::invalid_argument("calibration: delay_s: expected " + std::to_string(m) +
                                    " values, got " + std::to_string(delay_s.size()));
    for (size_t i = 0; i < m; i++) {
        if (!std::isfinite(dc[i].real()) || !std::isfinite(dc[i].imag()))
            throw std::invalid_argument("calibration: dc: non-finite value");
        if (!std::isfinite(gain_db[i]) || !std::isfinite(phase_rad[i]) ||
            !std::isfinite(delay_s[i]))
            throw std::invalid_argument(
                "calibration: gain_db/phase_rad/delay_s: non-finite value");
    }
    if (reference_channel < -1 || reference_channel >= int(m))
        throw std::invalid_argument("calibration: reference_channel out of range");
}

gr_complex calibration_coefficients::chain_response(int channel, double baseband_hz) const
{
    const double g = std::pow(10.0, gain_db.at(channel) / 20.0);
    const double a = phase_rad.at(channel) - 2.0 * M_PI * baseband_hz * delay_s.at(channel);
    return gr_complex(float(g * std::cos(a)), float(g * std::sin(a)));
}

std::string calibration_coefficients::to_json() const
{
    validate();
    std::ostringstream s;
    s << "{\n  \"thrumapper:calibration\": 1,\n  \"num_channels\": " << num_channels()
      << ",\n  \"reference_channel\": " << reference_channel << ",\n  \"source\": "
      << quoted(source) << ",\n  \"center_frequency_hz\": " << number(center_frequency_hz)
      << ",\n  \"sample_rate_hz\": " << number(sample_rate_hz) << ",\n  \"channels\": [\n";
    for (int m = 0; m < num_channels(); m++) {
        s << "    {\"dc\": [" << number(dc[m].real()) << ", " << number(dc[m].imag())
          << "], \"gain_db\": " << number(gain_db[m]) << ", \"phase_rad\": "
          << number(phase_rad[m]) << ", \"delay_s\": " << number(delay_s[m]) << "}"
          << (m + 1 < num_channels() ? ",\n" : "\n");
    }
    s << "  ]\n}\n";
    return s.str();
}

calibration_coefficients calibration_coefficients::from_json(const std::string& text)
{
    boost::property_tree::ptree root;
    std::istringstream in(text);
    try {
        boost::property_tree::read_json(in, root);
    } catch (const std::exception& e) {
        throw std::invalid_argument(std::string("calibration JSON: not valid JSON: ") +
                                    e.what());
    }
    if (root.find("thrumapper:calibration") == root.not_found())
        throw std::invalid_argument(
            "calibration JSON: thrumapper:calibration: missing (not a calibration file)");
    calibration_coefficients c;
    const auto& channels = child(root, "channels", "");
    for (const auto& item : channels) {
        const std::string where = "channels[" + std::to_string(c.gain_db.size()) + "].";
        const auto& dc = child(item.second, "dc", where);
        std::vector<double> parts;
        for (const auto& v : dc)
            parts.push_back(to_double(v.second, where + "dc"));
        if (parts.size() != 2)
            throw std::invalid_argument("calibration JSON: " + where + "dc: expected [re, im]");
        c.dc.emplace_back(float(parts[0]), float(parts[1]));
        c.gain_db.push_back(to_double(child(item.second, "gain_db", where), where + "gain_db"));
        c.phase_rad.push_back(
            to_double(child(item.second, "phase_rad", where), where + "phase_rad"));
        c.delay_s.push_back(to_double(child(item.second, "delay_s", where), where + "delay_s"));
    }
    if (c.gain_db.empty())
        throw std::invalid_argument("calibration JSON: channels: empty");
    const double declared = to_double(child(root, "num_channels", ""), "num_channels");
    if (declared != double(c.gain_db.size()))
        throw std::invalid_argument("calibration JSON: num_channels: says " +
                                    number(declared) + " but channels has " +
                                    std::to_string(c.gain_db.size()));
    c.reference_channel =
        int(to_double(child(root, "reference_channel", ""), "reference_channel"));
    c.source = child(root, "source", "").get_value<std::string>();
    c.center_frequency_hz =
        to_double(child(root, "center_frequency_hz", ""), "center_frequency_hz");
    c.sample_rate_hz = to_double(child(root, "sample_rate_hz", ""), "sample_rate_hz");
    c.validate();
    return c;
}

void calibration_coefficients::save(const std::string& path) const
{
    const std::string text = to_json();
    const std::string tmp = path + ".tmp";
    {
        std::ofstream out(tmp, std::ios::trunc);
        if (!out)
            throw std::runtime_error("calibration: cannot write " + tmp);
        out << text;
        if (!out)
            throw std::runtime_error("calibration: cannot write " + tmp);
    }
    if (std::rename(tmp.c_str(), path.c_str()) != 0)
        throw std::runtime_error("calibration: cannot rename " + tmp + " to " + path);
}

calibration_coefficients calibration_coefficients::load(const std::string& path)
{
    std::ifstream in(path);
    if (!in)
        throw std::invalid_argument("calibration: cannot read " + path);
    std::stringstream s;
    s << in.rdbuf();
    try {
        return from_json(s.str());
    } catch (const std::invalid_argument& e) {
        throw std::invalid_argument(std::string(e.what()) + " (in " + path + ")");
    }
}

// ---------------------------------------------------------------------------------------
// Estimation
// ---------------------------------------------------------------------------------------
channel_calibration::channel_calibration(ofdm_sounding::sptr sounding,
                                         const std::string& source,
                                         int reference_channel,
                                         const std::vector<gr_complex>& tx_weights)
    : d_sounding(sounding), d_source(source), d_reference(reference_channel)
{
    if (!sounding)
        throw std::invalid_argument("channel_calibration: a sounding description is required");
    if (source != "reference" && source != "direct_path")
        throw std::invalid_argument(
            "channel_calibration: source must be 'reference' or 'direct_path', got '" + source +
            "'");
    const int M = sounding->num_rx(), K = sounding->num_tx();
    if (reference_channel < -1 || reference_channel >= M)
        throw std::invalid_argument("channel_calibration: reference_channel must be -1 (the "
                                    "mean) or in [0, " +
                                    std::to_string(M) + ")");
    if (source == "direct_path" && sounding->mode() == sounding_mode::sequential)
        throw std::invalid_argument("channel_calibration: direct_path needs the weighted or "
                                    "interleaved sounding mode");
    d_weights = tx_weights.empty() ? sounding->radar()->tx_weights() : tx_weights;
    if (int(d_weights.size()) != K)
        throw std::invalid_argument("channel_calibration: expected K=" + std::to_string(K) +
                                    " TX weights, got " + std::to_string(d_weights.size()));
    d_fft = std::make_unique<gr::fft::fft_complex_fwd>(sounding->fft_len(), 1);
}

channel_calibration::~channel_calibration() = default;

calibration_coefficients channel_calibration::estimate(const gr_complex* const* channels,
                                                       int num_channels,
                                                       int length,
                                                       double center_frequency_hz)
{
    const auto& s = *d_sounding;
    const int F = s.fft_len(), M = num_channels;
    if (M != s.num_rx())
        throw std::invalid_argument("channel_calibration: expected M=" +
                                    std::to_string(s.num_rx()) + " channels");
    if (length < F)
        throw std::invalid_argument("channel_calibration: need at least fft_len samples");
    const int ref = d_reference < 0 ? 0 : d_reference;
    const double carrier = center_frequency_hz > 0 ? center_frequency_hz : s.lo_frequency_hz();
    calibration_coefficients c = calibration_coefficients::identity(M);
    c.reference_channel = d_reference;
    c.source = d_source;
    c.center_frequency_hz = carrier;
    c.sample_rate_hz = s.sample_rate_hz();

    // (i) DC offset: the mean over whole frames (a sounding frame has no DC of its own)
    const int mean_len = length >= s.frame_len() ? (length / s.frame_len()) * s.frame_len() : length;
    for (int m = 0; m < M; m++) {
        std::complex<double> sum = 0;
        for (int t = 0; t < mean_len; t++)
            sum += std::complex<double>(channels[m][t]);
        c.dc[m] = gr_complex(sum / double(mean_len));
        if (!std::isfinite(c.dc[m].real()) || !std::isfinite(c.dc[m].imag()))
            throw std::invalid_argument("channel_calibration: channel " + std::to_string(m) +
                                        " holds NaN/Inf");
    }

    // Cross-spectra against the reference channel over blocks of F samples.
    const int blocks = length / F;
    std::vector<std::vector<std::complex<double>>> cross(
        M, std::vector<std::complex<double>>(F, 0.0));
    std::vector<double> power(F, 0.0);
    std::vector<std::vector<gr_complex>> spectra(M, std::vector<gr_complex>(F));
    for (int b = 0; b < blocks; b++) {
        for (int m = 0; m < M; m++) {
            gr_complex* in = d_fft->get_inbuf();
            const gr_complex* x = channels[m] + size_t(b) * F;
            for (int t = 0; t < F; t++)
                in[t] = x[t] - c.dc[m];
            d_fft->execute();
            std::copy(d_fft->get_outbuf(), d_fft->get_outbuf() + F, spectra[m].begin());
        }
        for (int k = 0; k < F; k++) {
            const std::complex<double> r(spectra[ref][k]);
            power[k] += std::norm(r);
            for (int m = 0; m < M; m++)
                cross[m][k] += std::complex<double>(spectra[m][k]) * std::conj(r);
        }
    }

    // The direct-path model: what every RX element receives from the TX array.
    std::vector<std::vector<std::complex<double>>> model;
    if (d_source == "direct_path") {
        const auto& radar = *s.radar();
        const auto& tx = radar.tx_elements_m();
        const auto& rx = radar.rx_elements_m();
        const int K = radar.num_tx();
        model.assign(M, std::vector<std::complex<double>>(F, 0.0));
        std::vector<int> owner(F, -2); // interleaved: the element on each used bin
        if (s.mode() == sounding_mode::interleaved) {
            for (int n = 0; n < s.num_subcarriers(); n++)
                owner[s.subcarrier_bins()[n]] = s.tx_element_of_subcarrier(n);
        }
        for (int k = 0; k < F; k++) {
            const double f = carrier + s.bin_frequency_hz(k);
            for (int m = 0; m < M; m++) {
                std::complex<double> sum = 0;
                for (int e = 0; e < K; e++) {
                    if (s.mode() == sounding_mode::interleaved && owner[k] != e)
                        continue;
                    const double d = (tx.row(e) - rx.row(m)).norm();
                    const double lambda = speed_of_light_m_s / f;
                    const std::complex<double> w = (s.mode() == sounding_mode::interleaved)
                                                       ? 1.0
                                                       : std::complex<double>(d_weights[e]);
                    sum += w * lambda / (4.0 * M_PI * d) *
                           std::polar(1.0, -2.0 * M_PI * f * d / speed_of_light_m_s);
                }
                model[m][k] = sum;
            }
        }
    }

    // Bins that carry signal (DC excluded: it holds the chains' offsets).
    std::vector<double> weight(F, 0.0);
    double peak = 0;
    for (int k = 1; k < F; k++)
        peak = std::max(peak, power[k]);
    if (!(peak > 0))
        throw std::invalid_argument("channel_calibration: the reference channel holds no signal");
    for (int k = 1; k < F; k++) {
        if (power[k] < 1e-3 * peak)
            continue;
        if (!model.empty()) {
            double least = 1e300;
            for (int m = 0; m < M; m++)
                least = std::min(least, std::abs(model[m][k]));
            if (!(least > 0))
                continue;
        }
        weight[k] = power[k];
    }

    std::vector<double> delay(M), phase(M), gain(M);
    std::vector<std::complex<double>> ratio(F);
    const double spacing = s.bin_spacing_hz();
    for (int m = 0; m < M; m++) {
        for (int k = 0; k < F; k++) {
            if (weight[k] == 0.0) {
                ratio[k] = 0;
                continue;
            }
            ratio[k] = cross[m][k] / power[k];
            if (!model.empty())
                ratio[k] *= model[ref][k] / model[m][k];
        }
        // coarse delay: the mean phase step between neighbouring bins (in frequency order)
        std::complex<double> step = 0;
        for (int kk = -F / 2; kk < (F + 1) / 2 - 1; kk++) {
            const int a = (kk + F) % F, b = (kk + 1 + F) % F;
            if (weight[a] > 0 && weight[b] > 0)
                step += std::min(weight[a], weight[b]) * ratio[b] * std::conj(ratio[a]);
        }
        double tau = -std::arg(step) / (2.0 * M_PI * spacing);
        // phase at the LO, then a weighted straight-line fit of the residual phase
        auto derotated = [&](int k) {
            return ratio[k] * std::polar(1.0, 2.0 * M_PI * s.bin_frequency_hz(k) * tau);
        };
        std::complex<double> mean = 0;
        for (int k = 0; k < F; k++)
            if (weight[k] > 0)
                mean += weight[k] * derotated(k);
        double phi = std::arg(mean);
        double sw = 0, sf = 0, sp = 0, sff = 0, sfp = 0, sg = 0;
        for (int k = 0; k < F; k++) {
            if (weight[k] == 0.0)
                continue;
            const double w = weight[k], f = s.bin_frequency_hz(k);
            const double p = std::arg(derotated(k) * std::polar(1.0, -phi));
            sw += w;
            sf += w * f;
            sp += w * p;
            sff += w * f * f;
            sfp += w * f * p;
            sg += w * std::abs(ratio[k]);
        }
        const double det = sw * sff - sf * sf;
        if (det > 0) {
            const double slope = (sw * sfp - sf * sp) / det;
            const double intercept = (sp - slope * sf) / sw;
            tau -= slope / (2.0 * M_PI);
            phi += intercept;
        }
        delay[m] = tau;
        phase[m] = std::remainder(phi, 2.0 * M_PI);
        gain[m] = sg / sw;
        if (!(gain[m] > 0) || !std::isfinite(gain[m]))
            throw std::invalid_argument("channel_calibration: channel " + std::to_string(m) +
                                        " holds no signal");
    }
    if (d_reference < 0) { // align to the mean of all channels
        double mean_delay = 0, mean_log_gain = 0;
        std::complex<double> mean_phase = 0;
        for (int m = 0; m < M; m++) {
            mean_delay += delay[m] / M;
            mean_log_gain += std::log(gain[m]) / M;
            mean_phase += std::polar(1.0, phase[m]);
        }
        for (int m = 0; m < M; m++) {
            delay[m] -= mean_delay;
            gain[m] /= std::exp(mean_log_gain);
            phase[m] = std::remainder(phase[m] - std::arg(mean_phase), 2.0 * M_PI);
        }
    }
    for (int m = 0; m < M; m++) {
        c.gain_db[m] = 20.0 * std::log10(gain[m]);
        c.phase_rad[m] = phase[m];
        c.delay_s[m] = delay[m];
    }
    c.validate();
    return c;
}

// ---------------------------------------------------------------------------------------
// Correction
// ---------------------------------------------------------------------------------------
channel_corrector::channel_corrector(int num_channels, int fft_len, double sample_rate_hz)
    : d_channels(num_channels),
      d_taps(fft_len),
      d_block(next_pow2(8 * fft_len)),
      d_sample_rate_hz(sample_rate_hz)
{
    if (num_channels < 1)
        throw std::invalid_argument("channel_corrector: num_channels must be at least 1");
    if (fft_len < 2)
        throw std::invalid_argument("channel_corrector: fft_len must be at least 2");
    if (!(sample_rate_hz > 0))
        throw std::invalid_argument("channel_corrector: sample_rate_hz must be positive");
    d_fwd = std::make_unique<gr::fft::fft_complex_fwd>(d_block, 1);
    d_rev = std::make_unique<gr::fft::fft_complex_rev>(d_block, 1);
    set_coefficients(calibration_coefficients::identity(num_channels));
}

channel_corrector::~channel_corrector() = default;

void channel_corrector::set_coefficients(const calibration_coefficients& c)
{
    c.validate();
    if (c.num_channels() != d_channels)
        throw std::invalid_argument("channel_corrector: coefficients for " +
                                    std::to_string(c.num_channels()) + " channels, expected " +
                                    std::to_string(d_channels));
    const int L = d_taps, p = lookahead();
    d_coefficients = c;
    d_spectra.assign(d_channels, std::vector<gr_complex>(d_block));
    d_identity.assign(d_channels, false);
    d_dc_term.assign(d_channels, gr_complex(0, 0));
    gr::fft::fft_complex_rev taps_ifft(L, 1);
    for (int m = 0; m < d_channels; m++) {
        d_identity[m] = c.gain_db[m] == 0.0 && c.phase_rad[m] == 0.0 && c.delay_s[m] == 0.0;
        // C(f) = 1/β(f) at the L bins of the tap design
        gr_complex* in = taps_ifft.get_inbuf();
        for (int k = 0; k < L; k++) {
            const int kk = (k >= (L + 1) / 2) ? k - L : k;
            in[k] = gr_complex(1.0f, 0.0f) /
                    c.chain_response(m, kk * d_sample_rate_hz / L);
        }
        taps_ifft.execute();
        // causal taps g[i] = c[i - p]: lags -p ... L-1-p
        gr_complex* fin = d_fwd->get_inbuf();
        std::fill(fin, fin + d_block, gr_complex(0, 0));
        const gr_complex* taps = taps_ifft.get_outbuf();
        for (int i = 0; i < L; i++)
            fin[i] = taps[((i - p) % L + L) % L] / float(L);
        d_fwd->execute();
        for (int k = 0; k < d_block; k++)
            d_spectra[m][k] = d_fwd->get_outbuf()[k] / float(d_block);
        d_dc_term[m] = c.dc[m] / c.chain_response(m, 0.0);
    }
}

void channel_corrector::process(int channel, const gr_complex* in, gr_complex* out, int n)
{
    if (channel < 0 || channel >= d_channels)
        throw std::out_of_range("channel_corrector: channel out of range");
    const int L = d_taps, p = lookahead();
    const gr_complex dc = d_dc_term[channel];
    if (d_identity[channel]) {
        const gr_complex* x = in + (L - 1 - p);
        for (int i = 0; i < n; i++)
            out[i] = x[i] - dc;
        return;
    }
    const int step = d_block - (L - 1);
    const auto& spectrum = d_spectra[channel];
    for (int pos = 0; pos < n; pos += step) {
        const int count = std::min(step, n - pos);
        const int avail = count + L - 1;
        gr_complex* fin = d_fwd->get_inbuf();
        std::copy(in + pos, in + pos + avail, fin);
        std::fill(fin + avail, fin + d_block, gr_complex(0, 0));
        d_fwd->execute();
        const gr_complex* fout = d_fwd->get_outbuf();
        volk_32fc_x2_multiply_32fc(d_rev->get_inbuf(), fout, spectrum.data(), d_block);
        d_rev->execute();
        const gr_complex* y = d_rev->get_outbuf() + (L - 1);
        for (int i = 0; i < count; i++)
            out[pos + i] = y[i] - dc;
    }
}

} // namespace thrumapper
} // namespace gr
