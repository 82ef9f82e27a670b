#
# SPDX-License-Identifier: GPL-3.0-or-later
#
"""Small helpers the QA tests and the benchmarks share."""

import gc
import math
import time

import numpy as np

from . import bistatic

C = bistatic.SPEED_OF_LIGHT_M_S


def wait_for(predicate, timeout_s=10.0, poll_s=0.01):
    """Poll until predicate() holds or timeout_s passes; return its last value.

    A flowgraph runs in its own threads: a test that posts a message (`_post`) or starts a
    flowgraph waits for the effect with this, never with a bare sleep.
    """
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(poll_s)
    return predicate()


def free_finished_flowgraphs():
    """Free the reference cycles of finished flowgraphs now, in the calling (main) thread.

    Left to Python's cyclic collector they are freed wherever it next runs, now and then in
    the next flowgraph's Python block thread, which crashed qa_radio_chain about once in 20
    runs. QA classes that build flowgraphs call this in tearDown; so should a script that runs
    flowgraphs one after another (README, "Using it").
    """
    gc.collect()


def exact_echoes(pose, walls, radar, points=(), ghosts=False, max_range_m=8.0):
    """Exact echoes at a pose (paths dicts, as WallFusion.add takes) for the RadarGeometry
    `radar`: specular reflections of the wall segments (world [p0, p1]) whose
    specular point lies on the segment, point scatterers, and (ghosts) the double bounces
    between the first two walls. Power falls by 10 dB per wall a leg crosses (a hidden wall
    comes back about 20 dB below the one in front, as in the paper)."""
    out = []
    faces = []
    for p0, p1 in walls:
        p0, p1 = np.asarray(p0, float), np.asarray(p1, float)
        d = (p1 - p0) / np.hypot(*(p1 - p0))
        n = np.array([-d[1], d[0]])
        if (np.asarray(pose[:2]) - p0) @ n < 0:
            n = -n
        faces.append((p0, p1, n))

    def crossings(a, b, skip):
        count = 0
        for k, (q0, q1, _) in enumerate(faces):
            if k != skip and bistatic.segments_cross(a, b, q0, q1):
                count += 1
        return count

    TX, RX = radar.tx_centre_m, radar.rx_centre_m
    tx_w = bistatic.robot_to_world(TX, pose)
    rx_w = bistatic.robot_to_world(RX, pose)
    for k, (p0, p1, n) in enumerate(faces):
        q_r = bistatic.world_to_robot(p0, pose)
        n_r = bistatic.rotate(n, -pose[2])
        try:
            aoa, delay, point_r = bistatic.specular_path(q_r, n_r, TX, RX)
        except bistatic.GeometryError:
            continue
        point = bistatic.robot_to_world(point_r, pose)
        t = (point - p0) @ (p1 - p0) / ((p1 - p0) @ (p1 - p0))
        if not 0.0 < t < 1.0 or np.hypot(*(point - pose[:2])) > max_range_m:
            continue
        crossed = crossings(tx_w, point, k) + crossings(point, rx_w, k)
        out.append({"aoa_deg": math.degrees(aoa), "delay_s": delay, "power": 1e-5 / (C * delay) ** 2 * 0.1 ** crossed})
    for p in points:
        p_r = bistatic.world_to_robot(p, pose)
        delay = (np.hypot(*(p_r - TX)) + np.hypot(*(p_r - RX))) / C
        aoa = math.atan2(*(p_r - RX)[::-1])
        out.append({"aoa_deg": math.degrees(aoa) % 360, "delay_s": delay, "power": 3e-6 / (C * delay) ** 2})
    if ghosts and len(faces) >= 2:
        for a, b in ((0, 1), (1, 0)):
            fa, fb = faces[a], faces[b]
            path = bistatic.double_bounce_path(bistatic.world_to_robot(fa[0], pose), bistatic.rotate(fa[2], -pose[2]),
                                               bistatic.world_to_robot(fb[0], pose), bistatic.rotate(fb[2], -pose[2]),
                                               TX, RX)
            if path is not None:
                out.append({"aoa_deg": math.degrees(path[0]), "delay_s": path[1], "power": 1e-6 / (C * path[1]) ** 2})
    return out


def straight_poses(x0, x1, step=0.2, y=0.0):
    """Poses (x, y, heading) every `step` metres along x from x0 to x1, heading 0."""
    xs = np.arange(x0, x1 + 1e-9, step)
    return np.column_stack((xs, np.full_like(xs, y), np.zeros_like(xs)))


def drifting_corridor(length_m=20.0, scale_error=0.01, drift_deg_per_m=0.5, step_m=0.2):
    """A corridor `length_m` long between walls 2 m apart, closed 3 m past both ends, with
    door frames every 4 m on both sides (point scatterers), and an odometry `scale_error`
    long drifting `drift_deg_per_m` (the issue's 1 % and 0.5° per metre): (true poses,
    reported poses, walls, door frames)."""
    true = straight_poses(0.0, length_m, step_m)
    walls = [([-3.0, -1.0], [length_m + 3.0, -1.0]), ([-3.0, 1.0], [length_m + 3.0, 1.0]),
             ([-3.0, -1.0], [-3.0, 1.0]), ([length_m + 3.0, -1.0], [length_m + 3.0, 1.0])]
    frames = [np.array([x, y]) for x in range(2, int(length_m), 4) for y in (-1.0, 1.0)]
    reported = [true[0].copy()]
    step = step_m * (1.0 + scale_error)
    for _ in range(1, len(true)):
        heading = reported[-1][2] + math.radians(drift_deg_per_m) * step_m
        reported.append(np.array([reported[-1][0] + step * math.cos(reported[-1][2]),
                                  reported[-1][1] + step * math.sin(reported[-1][2]), heading]))
    return true, np.array(reported), walls, frames
