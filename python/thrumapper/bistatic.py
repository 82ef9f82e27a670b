#
# SPDX-License-Identifier: GPL-3.0-or-later
#
"""Bistatic geometry: from an echo's angle and delay to a wall point and orientation, and back.

Conventions are FORMATS.md's: robot frame (+x forward, +y left), metres, seconds, radians;
the angle of arrival θ is the bearing at the RX array centre, counter-clockwise from robot +x;
the delay τ is the propagation time from the TX array centre to the RX array centre.

A delay τ puts the reflection point on the ellipse whose foci are the two array centres and
whose distance sum is c·τ; the bearing puts it on the ray from the RX centre. With D the
vector from the TX centre to the RX centre, L = c·τ and u the unit bearing, the point
P = R + r·u on the ray satisfies |P − T| = L − r, so

    r = (L² − |D|²) / (2 (L + D·u)),

which is positive and finite exactly when L > |D|: an echo must come later than the direct
path. A specular reflector at P reflects T toward R (law of reflection), so its normal bisects
the unit vectors from P toward T and toward R: that is the ellipse's normal, and the wall's
face lies along the ellipse's tangent there. Each specular echo therefore gives a point and an
orientation.
"""

import math

import numpy as np

SPEED_OF_LIGHT_M_S = 299792458.0


class GeometryError(ValueError):
    """An echo that no reflector can produce (for instance a delay below the direct path's)."""


def _unit(v):
    v = np.asarray(v, dtype=float)
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    return v / np.where(n == 0.0, 1.0, n)


def bearing_vector(angle_rad):
    """Unit vectors [cos θ, sin θ], shape (..., 2)."""
    a = np.asarray(angle_rad, dtype=float)
    return np.stack((np.cos(a), np.sin(a)), axis=-1)


def direct_delay_s(tx_centre_m, rx_centre_m):
    """Delay of the direct TX-centre → RX-centre path, |T − R| / c."""
    return float(np.hypot(*(np.asarray(rx_centre_m, float) - np.asarray(tx_centre_m, float)))) / SPEED_OF_LIGHT_M_S


def reflection_range_m(aoa_rad, delay_s, tx_centre_m, rx_centre_m):
    """Distance r from the RX centre, along the bearing, to the reflection point (...,).

    Raises GeometryError when a delay is not finite or not longer than the direct path's.
    """
    tx = np.asarray(tx_centre_m, dtype=float)
    rx = np.asarray(rx_centre_m, dtype=float)
    d = rx - tx
    tau = np.asarray(delay_s, dtype=float)
    theta = np.asarray(aoa_rad, dtype=float)
    if not (np.all(np.isfinite(tau)) and np.all(np.isfinite(theta))):
        raise GeometryError("aoa_rad, delay_s: NaN or Inf")
    path_m = SPEED_OF_LIGHT_M_S * tau
    base_m = float(np.hypot(*d))
    if np.any(path_m <= base_m):
        worst = float(np.min(tau))
        raise GeometryError(
            f"delay_s: {worst * 1e9:.3f} ns is not longer than the direct path's {base_m / SPEED_OF_LIGHT_M_S * 1e9:.3f} ns; "
            "no reflector gives such an echo")
    u = bearing_vector(theta)
    return (path_m**2 - base_m**2) / (2.0 * (path_m + u @ d))


def reflection_point(aoa_rad, delay_s, tx_centre_m, rx_centre_m):
    """The specular reflection point and the reflector's unit normal, robot frame.

    Returns (point_m (..., 2), normal (..., 2)): the normal points from the wall toward the
    radar (it bisects the directions from the point to the two array centres), so the wall's
    face runs along (−n_y, n_x) through the point. Raises GeometryError on a delay that is not
    longer than the direct path's, or on NaN/Inf.
    """
    tx = np.asarray(tx_centre_m, dtype=float)
    rx = np.asarray(rx_centre_m, dtype=float)
    r = reflection_range_m(aoa_rad, delay_s, tx, rx)
    point = rx + r[..., None] * bearing_vector(aoa_rad)
    normal = _unit(_unit(tx - point) + _unit(rx - point))
    return point, normal


def incidence_angle_rad(point_m, normal, tx_centre_m):
    """Angle between the wall normal and the direction from the point to the TX centre."""
    to_tx = _unit(np.asarray(tx_centre_m, float) - np.asarray(point_m, float))
    return np.arccos(np.clip(np.sum(to_tx * np.asarray(normal, float), axis=-1), -1.0, 1.0))


def mirror(points_m, face_point_m, normal):
    """Mirror points in the line through face_point with unit normal (image method)."""
    p = np.asarray(points_m, dtype=float)
    n = _unit(normal)
    q = np.asarray(face_point_m, dtype=float)
    return p - 2.0 * np.sum((p - q) * n, axis=-1, keepdims=True) * n


def specular_path(face_point_m, normal, tx_centre_m, rx_centre_m):
    """The specular echo of an infinite flat wall (the line through face_point_m with this
    normal), by the image method: (aoa_rad, delay_s, reflection point (2,)).

    Raises GeometryError when the array centres are not both in front of the face.

    Plain float arithmetic: the CSI fits ask for it ~10^5 times a map.
    """
    tx_x, tx_y = float(tx_centre_m[0]), float(tx_centre_m[1])
    rx_x, rx_y = float(rx_centre_m[0]), float(rx_centre_m[1])
    q_x, q_y = float(face_point_m[0]), float(face_point_m[1])
    n_x, n_y = float(normal[0]), float(normal[1])
    length = math.sqrt(n_x * n_x + n_y * n_y)
    if length != 0.0:
        n_x, n_y = n_x / length, n_y / length
    if not ((tx_x - q_x) * n_x + (tx_y - q_y) * n_y > 0.0 and (rx_x - q_x) * n_x + (rx_y - q_y) * n_y > 0.0):
        raise GeometryError("specular_path: both array centres must be in front of the face (on the normal's side)")
    d = 2.0 * ((tx_x - q_x) * n_x + (tx_y - q_y) * n_y)
    v_x, v_y = tx_x - d * n_x - rx_x, tx_y - d * n_y - rx_y  # TX's image, seen from RX
    length_m = float(np.hypot(v_x, v_y))
    t = ((q_x - rx_x) * n_x + (q_y - rx_y) * n_y) / (v_x * n_x + v_y * n_y)
    point = np.array([rx_x + t * v_x, rx_y + t * v_y])
    return math.atan2(v_y, v_x) % (2.0 * math.pi), length_m / SPEED_OF_LIGHT_M_S, point


def double_bounce_path(first_point_m, first_normal, second_point_m, second_normal, tx_centre_m, rx_centre_m):
    """TX → wall 1 → wall 2 → RX by double imaging: (aoa_rad, delay_s, bounce points) or None
    when no such specular path exists (a bounce point on the wrong side or behind a focus).

    Plain float arithmetic: the fusion asks for it for every pair of walls at every pose."""
    tx_x, tx_y = float(tx_centre_m[0]), float(tx_centre_m[1])
    rx_x, rx_y = float(rx_centre_m[0]), float(rx_centre_m[1])
    q1x, q1y = float(first_point_m[0]), float(first_point_m[1])
    q2x, q2y = float(second_point_m[0]), float(second_point_m[1])
    n1x, n1y = float(first_normal[0]), float(first_normal[1])
    n2x, n2y = float(second_normal[0]), float(second_normal[1])
    l1 = math.hypot(n1x, n1y)
    l2 = math.hypot(n2x, n2y)
    if l1 == 0.0 or l2 == 0.0:
        return None
    n1x, n1y, n2x, n2y = n1x / l1, n1y / l1, n2x / l2, n2y / l2
    d = (tx_x - q1x) * n1x + (tx_y - q1y) * n1y
    i1x, i1y = tx_x - 2.0 * d * n1x, tx_y - 2.0 * d * n1y  # TX mirrored in wall 1
    d = (i1x - q2x) * n2x + (i1y - q2y) * n2y
    i2x, i2y = i1x - 2.0 * d * n2x, i1y - 2.0 * d * n2y  # ... and in wall 2
    vx, vy = i2x - rx_x, i2y - rx_y
    denom2 = vx * n2x + vy * n2y
    if abs(denom2) < 1e-12:
        return None
    t2 = ((q2x - rx_x) * n2x + (q2y - rx_y) * n2y) / denom2
    if not 0.0 < t2 < 1.0:
        return None
    p2x, p2y = rx_x + t2 * vx, rx_y + t2 * vy
    wx, wy = i1x - p2x, i1y - p2y
    denom1 = wx * n1x + wy * n1y
    if abs(denom1) < 1e-12:
        return None
    t1 = ((q1x - p2x) * n1x + (q1y - p2y) * n1y) / denom1
    if not 0.0 < t1 < 1.0:
        return None
    p1x, p1y = p2x + t1 * wx, p2y + t1 * wy
    # both reflections on the faces' front sides
    if ((tx_x - q1x) * n1x + (tx_y - q1y) * n1y <= 0 or (p2x - q1x) * n1x + (p2y - q1y) * n1y <= 0
            or (p1x - q2x) * n2x + (p1y - q2y) * n2y <= 0 or (rx_x - q2x) * n2x + (rx_y - q2y) * n2y <= 0):
        return None
    length_m = math.hypot(tx_x - p1x, tx_y - p1y) + math.hypot(p1x - p2x, p1y - p2y) + math.hypot(p2x - rx_x, p2y - rx_y)
    return (math.atan2(vy, vx) % (2.0 * math.pi), length_m / SPEED_OF_LIGHT_M_S,
            (np.array([p1x, p1y]), np.array([p2x, p2y])))


def robot_to_world(points_m, pose):
    """Points (..., 2) from the robot frame of pose [x, y, heading] to the world frame."""
    x, y, h = (float(v) for v in pose)
    c, s = math.cos(h), math.sin(h)
    p = np.asarray(points_m, dtype=float)
    if p.shape == (2,):  # one point (the CSI fits' many calls): the same arithmetic on floats
        px, py = float(p[0]), float(p[1])
        return np.array([x + c * px - s * py, y + s * px + c * py])
    return np.stack((x + c * p[..., 0] - s * p[..., 1], y + s * p[..., 0] + c * p[..., 1]), axis=-1)


def world_to_robot(points_m, pose):
    """Points (..., 2) from the world frame to the robot frame of pose [x, y, heading]."""
    x, y, h = (float(v) for v in pose)
    c, s = math.cos(h), math.sin(h)
    p = np.asarray(points_m, dtype=float)
    if p.shape == (2,):
        px, py = float(p[0]) - x, float(p[1]) - y
        return np.array([c * px + s * py, -s * px + c * py])
    p = p - np.array([x, y])
    return np.stack((c * p[..., 0] + s * p[..., 1], -s * p[..., 0] + c * p[..., 1]), axis=-1)


def rotate(vectors, angle_rad):
    """Rotate direction vectors (..., 2) counter-clockwise by angle_rad."""
    c, s = math.cos(angle_rad), math.sin(angle_rad)
    v = np.asarray(vectors, dtype=float)
    if v.shape == (2,):
        vx, vy = float(v[0]), float(v[1])
        return np.array([c * vx - s * vy, s * vx + c * vy])
    return np.stack((c * v[..., 0] - s * v[..., 1], s * v[..., 0] + c * v[..., 1]), axis=-1)


def lines_meet(point_a, normal_a, point_b, normal_b, min_sin=1e-6):
    """Where two lines (a point on each and its normal) meet, (2,). Raises GeometryError when
    they are parallel to within min_sin (the sine of the angle between them)."""
    a = np.vstack((np.asarray(normal_a, float), np.asarray(normal_b, float)))
    if abs(np.linalg.det(a)) < min_sin * np.hypot(*a[0]) * np.hypot(*a[1]):
        raise GeometryError("lines_meet: the lines are parallel")
    return np.linalg.solve(a, [np.dot(point_a, normal_a), np.dot(point_b, normal_b)])


def segments_cross(p0, p1, a, b):
    """Whether segment p0→p1 crosses segment a→b (proper crossing), broadcasting over leading
    dimensions: p0, p1 (..., 2) against a, b (..., 2)."""
    p0, p1, a, b = (np.asarray(v, dtype=float) for v in (p0, p1, a, b))

    def orient(o, u, w):
        return (u[..., 0] - o[..., 0]) * (w[..., 1] - o[..., 1]) - (u[..., 1] - o[..., 1]) * (w[..., 0] - o[..., 0])

    d1 = orient(a, b, p0)
    d2 = orient(a, b, p1)
    d3 = orient(p0, p1, a)
    d4 = orient(p0, p1, b)
    return (d1 * d2 < 0) & (d3 * d4 < 0)


def segments_distance(p0, p1, a, b):
    """The shortest distance between segment p0→p1 and segment a→b, broadcasting over
    leading dimensions as segments_cross: 0 where they cross, else the nearest of the four
    ends to the other segment."""
    p0, p1, a, b = (np.asarray(v, dtype=float) for v in (p0, p1, a, b))

    def to_segment(q, u, w):
        d = w - u
        t = np.clip(np.sum((q - u) * d, axis=-1) / np.maximum(np.sum(d * d, axis=-1), 1e-300), 0.0, 1.0)
        return np.hypot(*np.moveaxis(q - (u + t[..., None] * d), -1, 0))

    ends = np.minimum(np.minimum(to_segment(p0, a, b), to_segment(p1, a, b)),
                      np.minimum(to_segment(a, p0, p1), to_segment(b, p0, p1)))
    return np.where(segments_cross(p0, p1, a, b), 0.0, ends)


def wall_ends(walls, margin_m=0.0):
    """The end points (a (W, 2), b (W, 2)) of wall dicts (centre, direction, t0, t1), each
    extended by margin_m: one number, or one per wall."""
    margins = np.broadcast_to(np.asarray(margin_m, float), (len(walls),))
    a = np.array([w["centre"] + (w["t0"] - m) * w["direction"] for w, m in zip(walls, margins)]).reshape(-1, 2)
    b = np.array([w["centre"] + (w["t1"] + m) * w["direction"] for w, m in zip(walls, margins)]).reshape(-1, 2)
    return a, b


def segment_crosses(p0x, p0y, p1x, p1y, ax, ay, bx, by):
    """segments_cross for one pair of segments given as floats (the same arithmetic, without
    numpy's overhead on 2-vectors: the CSI fits ask it for every trial wall and pose)."""
    d1 = (bx - ax) * (p0y - ay) - (by - ay) * (p0x - ax)
    d2 = (bx - ax) * (p1y - ay) - (by - ay) * (p1x - ax)
    if not d1 * d2 < 0:
        return False
    d3 = (p1x - p0x) * (ay - p0y) - (p1y - p0y) * (ax - p0x)
    d4 = (p1x - p0x) * (by - p0y) - (p1y - p0y) * (bx - p0x)
    return d3 * d4 < 0
