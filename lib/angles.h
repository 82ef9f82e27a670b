/* -*- c++ -*- */
/*
 * SPDX-License-Identifier: GPL-3.0-or-later
 */
// Angle helpers the blocks share (internal: blocks take degrees, the cores radians).
#ifndef INCLUDED_THRUMAPPER_ANGLES_H
#define INCLUDED_THRUMAPPER_ANGLES_H

#include <cmath>
#include <vector>

namespace gr {
namespace thrumapper {

inline std::vector<double> degrees_to_radians(const std::vector<double>& degrees)
{
    std::vector<double> radians;
    radians.reserve(degrees.size());
    for (double d : degrees)
        radians.push_back(d * M_PI / 180.0);
    return radians;
}

//! Distance between two bearings on the circle, radians in [0, π].
inline double angle_distance(double a_rad, double b_rad)
{
    const double d = std::fmod(std::abs(a_rad - b_rad), 2 * M_PI);
    return std::min(d, 2 * M_PI - d);
}

} // namespace thrumapper
} // namespace gr

#endif
