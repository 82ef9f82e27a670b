/* -*- c++ -*- */
/*
 * SPDX-License-Identifier: GPL-3.0-or-later
 */
#include <gnuradio/thrumapper/ofdm_sounding.h>
#include <algorithm>
#include <cmath>
#include <cstring>
#include <numeric>
#include <sstream>
#include <stdexcept>

namespace gr {
namespace thrumapper {

namespace {
std::string fmt(double v)
{
    std::ostringstream s;
    s.precision(10);
    s << v;
    return s.str();
}

//! exp(-jπ·u·q(t)/L) with q = t² (even L) or t(t+1) (odd L): a Zadoff-Chu sequence.
std::vector<gr_complex> zadoff_chu(int length, int root)
{
    std::vector<gr_complex> x(length);
    for (int t = 0; t < length; t++) {
        // q mod 2L keeps the phase argument small and exact
        const long long q = (length % 2 == 0) ? (long long)t * t : (long long)t * (t + 1);
        const long long r = (q * root) % (2LL * length);
        const double phase = -M_PI * double(r) / length;
        x[t] = gr_complex(float(std::cos(phase)), float(std::sin(phase)));
    }
    return x;
}

int coprime_root(int length)
{
    for (int u : { 3, 5, 7, 11, 13, 1 })
        if (std::gcd(u, length) == 1)
            return u;
    return 1;
}

int next_pow2(int n)
{
    int p = 1;
    while (p < n)
        p <<= 1;
    return p;
}
} // namespace

ofdm_sounding::sptr ofdm_sounding::make(radar_description::sptr radar,
                                        double sample_rate_hz,
                                        int fft_len,
                                        int cp_len,
                                        int num_symbols,
                                        int preamble_len,
                                        int gap_len,
                                        sounding_mode mode,
                                        double tuning_offset_hz)
{
    return std::make_shared<ofdm_sounding>(radar,
                                           sample_rate_hz,
                                           fft_len,
                                           cp_len,
                                           num_symbols,
                                           preamble_len,
                                           gap_len,
                                           mode,
                                           tuning_offset_hz);
}

ofdm_sounding::ofdm_sounding(radar_description::sptr radar,
                             double sample_rate_hz,
                             int fft_len,
                             int cp_len,
                             int num_symbols,
                             int preamble_len,
                             int gap_len,
                             sounding_mode mode,
                             double tuning_offset_hz)
    : d_radar(radar),
      d_sample_rate_hz(sample_rate_hz),
      d_fft_len(fft_len),
      d_cp_len(cp_len),
      d_num_symbols(num_symbols),
      d_preamble_len(preamble_len),
      d_gap_len(gap_len),
      d_mode(mode),
      d_tuning_offset_hz(tuning_offset_hz)
{
    const std::string where = "ofdm_sounding: ";
    if (!radar)
        throw std::invalid_argument(where + "a radar description is required");
    if (!(sample_rate_hz > 0) || !std::isfinite(sample_rate_hz))
        throw std::invalid_argument(where + "sample_rate_hz must be positive, got " +
                                    fmt(sample_rate_hz));
    if (fft_len < 8)
        throw std::invalid_argument(where + "fft_len must be at least 8, got " +
                                    std::to_string(fft_len));
    if (cp_len < 0 || cp_len > fft_len)
        throw std::invalid_argument(where + "cp_len must be in [0, fft_len], got " +
                                    std::to_string(cp_len));
    if (num_symbols < 1)
        throw std::invalid_argument(where + "num_symbols must be at least 1, got " +
                                    std::to_string(num_symbols));
    if (preamble_len < 16)
        throw std::invalid_argument(where + "preamble_len must be at least 16, got " +
                                    std::to_string(preamble_len));
    if (gap_len < 0)
        throw std::invalid_argument(where + "gap_len must be >= 0, got " +
                                    std::to_string(gap_len));
    if (mode != sounding_mode::weighted && mode != sounding_mode::sequential &&
        mode != sounding_mode::interleaved)
        throw std::invalid_argument(where + "unknown sounding mode");
    if (!std::isfinite(tuning_offset_hz))
        throw std::invalid_argument(where + "tuning_offset_hz must be finite");

    const int K = radar->num_tx(), N = radar->num_subcarriers(), F = fft_len;
    if (mode == sounding_mode::interleaved && N < K)
        throw std::invalid_argument(where + "interleaved mode needs at least K=" +
                                    std::to_string(K) + " subcarriers");
    if (N > F)
        throw std::invalid_argument(where + "fft_len=" + std::to_string(F) +
                                    " is smaller than the N=" + std::to_string(N) +
                                    " subcarriers");
    const double spacing = bin_spacing_hz();
    const auto& offsets = radar->subcarrier_offsets_hz();
    d_bins.resize(N);
    d_signed_bins.resize(N);
    for (int n = 0; n < N; n++) {
        const double x = (offsets[n] - tuning_offset_hz) / spacing;
        const long long k = std::llround(x);
        if (std::abs(x - double(k)) > 1e-6 * std::max(1.0, std::abs(x)))
            throw std::invalid_argument(
                where + "subcarrier " + std::to_string(n) + " (offset " + fmt(offsets[n]) +
                " Hz) is not on an FFT bin: the bin spacing sample_rate_hz/fft_len is " +
                fmt(spacing) + " Hz; choose sample_rate_hz and fft_len so that it divides "
                "every offset (e.g. 120e6 and 256 for N=128 over 120 MHz), or set "
                "tuning_offset_hz");
        if (k == 0)
            throw std::invalid_argument(
                where + "subcarrier " + std::to_string(n) +
                " falls on the radios' DC (bin 0), where their DC offset lies; set "
                "tuning_offset_hz to move it off DC");
        if (k < -F / 2 || k >= (F + 1) / 2)
            throw std::invalid_argument(where + "subcarrier " + std::to_string(n) +
                                        " is outside the sampled band ±sample_rate_hz/2");
        d_signed_bins[n] = int(k);
        d_bins[n] = int(((k % F) + F) % F);
    }
    for (int n = 1; n < N; n++)
        if (d_signed_bins[n] <= d_signed_bins[n - 1])
            throw std::invalid_argument(where + "subcarrier offsets must be ascending");

    // Pilots: a Zadoff-Chu sequence over the used subcarriers.
    d_pilots = zadoff_chu(N, coprime_root(N));
    // Preamble: a chirp (Zadoff-Chu in time, root 1) at the training's RMS level.
    d_preamble = zadoff_chu(preamble_len, 1);
    const float level = float(std::sqrt(double(N) / F));
    for (auto& v : d_preamble)
        v *= level;

    // The periodic pilot symbol(s): one for every element, or one per element (interleaved).
    const int patterns = (mode == sounding_mode::interleaved) ? K : 1;
    std::vector<std::vector<gr_complex>> symbol(patterns, std::vector<gr_complex>(F));
    gr::fft::fft_complex_rev ifft(F, 1);
    const float scale = float(1.0 / std::sqrt(double(F)));
    for (int p = 0; p < patterns; p++) {
        gr_complex* in = ifft.get_inbuf();
        std::fill(in, in + F, gr_complex(0, 0));
        for (int n = 0; n < N; n++)
            if (patterns == 1 || n % K == p)
                in[d_bins[n]] = d_pilots[n];
        ifft.execute();
        const gr_complex* out = ifft.get_outbuf();
        for (int t = 0; t < F; t++)
            symbol[p][t] = out[t] * scale;
    }

    const int P = frame_len(), L = slot_len();
    d_frames.assign(K, std::vector<gr_complex>(P, gr_complex(0, 0)));
    for (int e = 0; e < K; e++) {
        auto& f = d_frames[e];
        std::copy(d_preamble.begin(), d_preamble.end(), f.begin());
        for (int s = 0; s < num_slots(); s++) {
            const std::vector<gr_complex>* pattern = nullptr;
            if (mode == sounding_mode::weighted)
                pattern = &symbol[0];
            else if (mode == sounding_mode::sequential)
                pattern = (s == e) ? &symbol[0] : nullptr;
            else
                pattern = &symbol[e];
            if (!pattern)
                continue;
            gr_complex* slot = f.data() + slot_start(s);
            for (int u = 0; u < L; u++)
                slot[u] = (*pattern)[(((u - cp_len) % F) + F) % F];
        }
        // A frame without DC: the mean of any whole number of frames is then the radios' DC
        // offset alone (the calibrator measures it so). The preamble takes the correction:
        // a constant of about 1% of its level, far below its correlation peak.
        std::complex<double> sum = 0;
        for (const auto& v : f)
            sum += std::complex<double>(v);
        const gr_complex shift = gr_complex(sum / double(preamble_len));
        for (int t = 0; t < preamble_len; t++)
            f[t] -= shift;
    }
}

double ofdm_sounding::bin_frequency_hz(int bin) const
{
    const int k = (bin >= (d_fft_len + 1) / 2) ? bin - d_fft_len : bin;
    return k * bin_spacing_hz();
}

int ofdm_sounding::tx_element_of_subcarrier(int n) const
{
    if (n < 0 || n >= num_subcarriers())
        throw std::out_of_range("ofdm_sounding: subcarrier index out of range");
    return d_mode == sounding_mode::interleaved ? n % num_tx() : -1;
}

void ofdm_sounding::frame_samples(int element,
                                  const std::vector<gr_complex>& weights,
                                  gr_complex* out) const
{
    if (element < 0 || element >= num_tx())
        throw std::out_of_range("ofdm_sounding: TX element index out of range");
    const auto& f = d_frames[element];
    if (d_mode != sounding_mode::weighted) {
        std::copy(f.begin(), f.end(), out);
        return;
    }
    const auto& w = weights.empty() ? d_radar->tx_weights() : weights;
    if (static_cast<int>(w.size()) != num_tx())
        throw std::invalid_argument("ofdm_sounding: expected K=" + std::to_string(num_tx()) +
                                    " weights, got " + std::to_string(w.size()));
    const gr_complex g = w[element];
    for (size_t i = 0; i < f.size(); i++)
        out[i] = f[i] * g;
}

std::string ofdm_sounding::to_string() const
{
    static const char* names[] = { "weighted", "sequential", "interleaved" };
    std::ostringstream s;
    s << "OFDM sounding: " << num_subcarriers() << " subcarriers, FFT " << d_fft_len
      << " at " << d_sample_rate_hz / 1e6 << " MS/s (bins " << bin_spacing_hz() / 1e3
      << " kHz apart, LO at carrier " << (d_tuning_offset_hz >= 0 ? "+ " : "- ")
      << std::abs(d_tuning_offset_hz) << " Hz), CP " << d_cp_len << ", " << d_num_symbols
      << " symbols per slot, " << num_slots() << " slot(s), preamble " << d_preamble_len
      << ", gap " << d_gap_len << ": frame of " << frame_len() << " samples ("
      << frame_duration_s() * 1e6 << " us), mode " << names[int(d_mode)];
    return s.str();
}

// ---------------------------------------------------------------------------------------
// Demodulator
// ---------------------------------------------------------------------------------------
ofdm_demodulator::ofdm_demodulator(ofdm_sounding::sptr sounding,
                                   int search_window,
                                   int timing_backoff,
                                   double detection_threshold)
    : d_sounding(sounding),
      d_search_window(search_window),
      d_backoff(timing_backoff),
      d_threshold(detection_threshold)
{
    const std::string where = "ofdm_demodulator: ";
    if (!sounding)
        throw std::invalid_argument(where + "a sounding description is required");
    if (search_window < 0)
        throw std::invalid_argument(where + "search_window must be >= 0");
    if (timing_backoff < 0 || timing_backoff > sounding->cp_len())
        throw std::invalid_argument(where + "timing_backoff must be in [0, cp_len=" +
                                    std::to_string(sounding->cp_len()) + "], got " +
                                    std::to_string(timing_backoff));
    if (!(detection_threshold > 0.0 && detection_threshold < 1.0))
        throw std::invalid_argument(where + "detection_threshold must be in (0, 1)");
    const int F = sounding->fft_len(), Lp = sounding->preamble_len();
    d_corr_len = next_pow2(Lp + 2 * search_window);
    d_fft = std::make_unique<gr::fft::fft_complex_fwd>(F, 1);
    d_corr_fwd = std::make_unique<gr::fft::fft_complex_fwd>(d_corr_len, 1);
    d_corr_rev = std::make_unique<gr::fft::fft_complex_rev>(d_corr_len, 1);
    gr_complex* in = d_corr_fwd->get_inbuf();
    std::fill(in, in + d_corr_len, gr_complex(0, 0));
    const auto& p = sounding->preamble();
    std::copy(p.begin(), p.end(), in);
    d_corr_fwd->execute();
    d_preamble_spectrum.resize(d_corr_len);
    for (int k = 0; k < d_corr_len; k++)
        d_preamble_spectrum[k] = std::conj(d_corr_fwd->get_outbuf()[k]) / float(d_corr_len);
    d_preamble_energy = 0;
    for (const auto& v : p)
        d_preamble_energy += std::norm(v);
    d_metric_num.resize(2 * search_window + 1);
    d_metric_den.resize(2 * search_window + 1);
    d_energy_prefix.resize(Lp + 2 * search_window + 1);
    d_acc.resize(sounding->num_subcarriers());
    d_phasors.resize(F);
    for (int i = 0; i < F; i++) {
        const double a = -2.0 * M_PI * i / F;
        d_phasors[i] = gr_complex(float(std::cos(a)), float(std::sin(a)));
    }
}

ofdm_demodulator::~ofdm_demodulator() = default;

int ofdm_demodulator::span() const { return d_sounding->burst_len() + 2 * d_search_window; }

ofdm_demodulator::detection ofdm_demodulator::detect(const gr_complex* const* channels,
                                                     int num_channels)
{
    const int Lp = d_sounding->preamble_len(), lags = 2 * d_search_window + 1;
    const int len = Lp + 2 * d_search_window;
    std::fill(d_metric_num.begin(), d_metric_num.end(), 0.0f);
    std::fill(d_metric_den.begin(), d_metric_den.end(), 0.0f);
    for (int m = 0; m < num_channels; m++) {
        const gr_complex* x = channels[m];
        gr_complex* in = d_corr_fwd->get_inbuf();
        std::copy(x, x + len, in);
        std::fill(in + len, in + d_corr_len, gr_complex(0, 0));
        d_corr_fwd->execute();
        const gr_complex* spec = d_corr_fwd->get_outbuf();
        gr_complex* rin = d_corr_rev->get_inbuf();
        for (int k = 0; k < d_corr_len; k++)
            rin[k] = spec[k] * d_preamble_spectrum[k];
        d_corr_rev->execute();
        const gr_complex* corr = d_corr_rev->get_outbuf();
        d_energy_prefix[0] = 0.0;
        for (int t = 0; t < len; t++)
            d_energy_prefix[t + 1] = d_energy_prefix[t] + std::norm(x[t]);
        for (int l = 0; l < lags; l++) {
            d_metric_num[l] += std::norm(corr[l]);
            d_metric_den[l] += float(d_energy_prefix[l + Lp] - d_energy_prefix[l]);
        }
    }
    detection best{ false, 0, -1.0 };
    int best_lag = -1;
    for (int l = 0; l < lags; l++) {
        if (!(d_metric_den[l] > 0.0f))
            continue;
        const double metric = d_metric_num[l] / (d_preamble_energy * d_metric_den[l]);
        if (metric > best.metric) { // false for NaN: a frame with NaN/Inf is never found
            best.metric = metric;
            best_lag = l;
        }
    }
    if (best_lag < 0)
        return detection{ false, 0, 0.0 };
    best.offset = best_lag - d_search_window;
    best.found = best.metric >= d_threshold;
    return best;
}

void ofdm_demodulator::estimate(const gr_complex* const* channels,
                                int num_channels,
                                int offset,
                                double fractional_offset_samples,
                                gr_complex* csi)
{
    const auto& s = *d_sounding;
    const int F = s.fft_len(), N = s.num_subcarriers(), J = s.num_symbols();
    if (offset < -d_search_window || offset > d_search_window)
        throw std::invalid_argument("ofdm_demodulator: offset outside the search window");
    const int delta = offset - d_backoff;
    const auto& bins = s.subcarrier_bins();
    const auto& signed_bins = s.subcarrier_signed_bins();
    const auto& pilots = s.pilots();
    const float scale = float(1.0 / (std::sqrt(double(F)) * J));
    const bool fractional = fractional_offset_samples != 0.0;
    for (int slot = 0; slot < s.num_slots(); slot++) {
        for (int m = 0; m < num_channels; m++) {
            std::fill(d_acc.begin(), d_acc.end(), gr_complex(0, 0));
            for (int j = 0; j < J; j++) {
                const gr_complex* w =
                    channels[m] + d_search_window + s.window_start(slot, j) + delta;
                std::memcpy(d_fft->get_inbuf(), w, sizeof(gr_complex) * F);
                d_fft->execute();
                const gr_complex* y = d_fft->get_outbuf();
                for (int n = 0; n < N; n++)
                    d_acc[n] += y[bins[n]];
            }
            gr_complex* out = csi + (size_t(slot) * num_channels + m) * N;
            for (int n = 0; n < N; n++) {
                // the window started delta samples late: undo its phase ramp e^{+j2πkΔ/F}
                const long long idx = ((long long)signed_bins[n] * delta) % F;
                gr_complex v = d_acc[n] * std::conj(pilots[n]) * scale *
                               d_phasors[size_t((idx + F) % F)];
                if (fractional) { // the nominal start is fractional_offset after the pointer
                    const double a = 2.0 * M_PI * signed_bins[n] * fractional_offset_samples / F;
                    v *= gr_complex(float(std::cos(a)), float(std::sin(a)));
                }
                out[n] = v;
            }
        }
    }
}

} // namespace thrumapper
} // namespace gr
