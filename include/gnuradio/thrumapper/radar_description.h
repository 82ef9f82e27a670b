/* -*- c++ -*- */
/*
 * SPDX-License-Identifier: GPL-3.0-or-later
 */
#ifndef INCLUDED_THRUMAPPER_RADAR_DESCRIPTION_H
#define INCLUDED_THRUMAPPER_RADAR_DESCRIPTION_H

#include <gnuradio/gr_complex.h>
#include <gnuradio/thrumapper/api.h>
#include <Eigen/Dense>
#include <memory>
#include <string>
#include <vector>

namespace gr {
namespace thrumapper {

//! Speed of light in vacuum, m/s (FORMATS.md).
constexpr double speed_of_light_m_s = 299792458.0;

/*!
 * \brief The one description of the bistatic radar that every block takes.
 * \ingroup thrumapper
 *
 * Holds the TX and RX element positions in the robot frame (metres, +x forward, +y left),
 * the carrier, the used subcarrier offsets and the default TX weights. Shared by pointer,
 * like digital.constellation: make one in a GRC variable block and pass it to every block.
 * Immutable once made, so blocks may read it from any thread.
 */
class THRUMAPPER_API radar_description
{
public:
    typedef std::shared_ptr<radar_description> sptr;
    //! Element positions, one row [x, y] per element, metres in the robot frame.
    using positions_t = Eigen::Matrix<double, Eigen::Dynamic, 2, Eigen::RowMajor>;

    /*!
     * \brief A radar from explicit element positions.
     * \param tx_elements_m K×2 TX element positions, robot frame.
     * \param rx_elements_m M×2 RX element positions, robot frame.
     * \param carrier_hz the carrier fc.
     * \param subcarrier_offsets_hz N used subcarrier offsets Δf_n, ascending.
     * \param tx_weights K complex TX weights; empty means all ones.
     */
    static sptr make(const positions_t& tx_elements_m,
                     const positions_t& rx_elements_m,
                     double carrier_hz,
                     const std::vector<double>& subcarrier_offsets_hz,
                     const std::vector<gr_complex>& tx_weights = {});

    /*!
     * \brief The ThruMapper layout: two equal UCAs on the robot's x axis, the TX array
     * centred at (-baseline/2, 0) and the RX array at (+baseline/2, 0), N subcarriers
     * spread uniformly over the bandwidth around the carrier.
     */
    static sptr make_uca_pair(int elements = 8,
                              double radius_m = 0.08,
                              double baseline_m = 0.7,
                              double carrier_hz = 2.44e9,
                              double bandwidth_hz = 120e6,
                              int subcarriers = 128,
                              double rotation_rad = 0.0);

    //! Positions of a uniform circular array; element i at angle rotation + 2πi/count.
    static positions_t uca_positions(int count,
                                     double radius_m,
                                     double rotation_rad = 0.0,
                                     double centre_x_m = 0.0,
                                     double centre_y_m = 0.0);
    //! Positions of a uniform linear array along the direction axis_rad, centred.
    static positions_t ula_positions(int count,
                                     double spacing_m,
                                     double axis_rad = 0.0,
                                     double centre_x_m = 0.0,
                                     double centre_y_m = 0.0);
    //! N offsets uniformly spaced by bandwidth/N, centred on zero, ascending.
    static std::vector<double> uniform_subcarriers(int count, double bandwidth_hz);

    const positions_t& tx_elements_m() const { return d_tx; }
    const positions_t& rx_elements_m() const { return d_rx; }
    Eigen::Vector2d tx_centre_m() const;
    Eigen::Vector2d rx_centre_m() const;
    double carrier_hz() const { return d_carrier_hz; }
    const std::vector<double>& subcarrier_offsets_hz() const { return d_offsets_hz; }
    const std::vector<gr_complex>& tx_weights() const { return d_tx_weights; }
    int num_tx() const { return static_cast<int>(d_tx.rows()); }
    int num_rx() const { return static_cast<int>(d_rx.rows()); }
    int num_subcarriers() const { return static_cast<int>(d_offsets_hz.size()); }
    //! True when the subcarriers are uniformly spaced (to 1e-6 relative).
    bool uniform_spacing() const { return d_uniform; }
    //! The subcarrier spacing; the mean spacing when not uniform.
    double subcarrier_spacing_hz() const;
    //! Distance between the array centres.
    double baseline_m() const;
    //! Delay of the direct path between the array centres, |c_tx - c_rx| / c (FORMATS.md).
    double direct_delay_s() const;
    //! Bearing of the TX centre seen from the RX centre, radians CCW from robot +x.
    double direct_aoa_rad() const;
    //! A one-paragraph human-readable summary.
    std::string to_string() const;

    radar_description(const positions_t& tx_elements_m,
                      const positions_t& rx_elements_m,
                      double carrier_hz,
                      const std::vector<double>& subcarrier_offsets_hz,
                      const std::vector<gr_complex>& tx_weights);

private:
    positions_t d_tx;
    positions_t d_rx;
    double d_carrier_hz;
    std::vector<double> d_offsets_hz;
    std::vector<gr_complex> d_tx_weights;
    bool d_uniform;
};

} // namespace thrumapper
} // namespace gr

#endif
