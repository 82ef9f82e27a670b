#
# SPDX-License-Identifier: GPL-3.0-or-later
#
"""Corner candidates: returns that stay at one point of the world while the robot moves.

A flat wall answers from its specular point, which slides along the wall with the robot; a
dihedral corner (two walls meeting at a right angle) answers over ±45° of aspect, always from
its apex A: its two reflections make a point reflection through A, so the TX centre's image
is I = 2A − T, and the echo arrives at the RX centre R from I's bearing after c·τ = |I − R|.
Each path of each pose is therefore located at A = (R + c·τ·u(θ) + T) / 2 in the world frame
(for a flat wall that is the foot of T on the wall, which moves with the robot); located
points that stay within `radius_m` over poses spanning at least `min_span_m` of travel are a
corner candidate. Its bearing from the TX centre can be given to null_steering_weights
as a far-field null, or its (angle, delay) to projection_canceller.
"""

import math
from dataclasses import dataclass, field

import numpy as np

from . import bistatic


@dataclass
class CornerCandidate:
    point_m: np.ndarray            # (2,) world frame, the median of the located points
    spread_m: float                # rms distance of the located points from it
    pose_indices: list = field(default_factory=list)  # the pose groups that saw it
    travel_span_m: float = 0.0     # how far apart those poses are
    power: float = 0.0             # median power of its returns

    def bearing_from_tx_deg(self, pose, tx_centre_m):
        """Bearing of the corner from the TX centre at this pose (robot frame, degrees)."""
        p = bistatic.world_to_robot(self.point_m, pose)
        d = p - np.asarray(tx_centre_m, float)
        return math.degrees(math.atan2(d[1], d[0])) % 360.0


def locate_paths(results, tx_centre_m, rx_centre_m, margin_s=1.0e-9):
    """Dihedral apexes A = (R + c·τ·u(θ) + T)/2 of every path of every pose group, world frame.

    results: run_survey's dicts (or any with "pose" and "paths" [{"aoa_deg", "delay_s",
    "power"}]). Paths no later than the direct path plus margin_s are skipped (no reflector
    answers before the direct path). Returns an array of rows [x, y, pose index, power].
    """
    direct_s = bistatic.direct_delay_s(tx_centre_m, rx_centre_m)
    rows = []
    for i, res in enumerate(results):
        pose = np.asarray(res["pose"], float)
        if pose.shape != (3,) or not np.all(np.isfinite(pose)):
            raise ValueError(f"pose group {i}: pose must be three finite numbers, got {res['pose']}")
        for p in res["paths"]:
            if not (math.isfinite(p["delay_s"]) and math.isfinite(p["aoa_deg"])):
                continue
            if p["delay_s"] <= direct_s + margin_s:
                continue
            image = np.asarray(rx_centre_m, float) + bistatic.SPEED_OF_LIGHT_M_S * p["delay_s"] * \
                bistatic.bearing_vector(math.radians(p["aoa_deg"]))
            apex = 0.5 * (image + np.asarray(tx_centre_m, float))
            world = bistatic.robot_to_world(apex, pose)
            rows.append([world[0], world[1], i, p["power"]])
    return np.asarray(rows, float).reshape(-1, 4)


def find_corner_candidates(results, tx_centre_m, rx_centre_m, radius_m=0.15, min_span_m=0.5,
                           min_poses=4):
    """Corner candidates in a sequence of pose groups (see the module's description)."""
    located = locate_paths(results, tx_centre_m, rx_centre_m)
    if located.shape[0] == 0:
        return []
    positions = np.array([np.asarray(r["pose"], float)[:2] for r in results])
    order = np.argsort(-located[:, 3])  # strongest first seeds the clusters
    used = np.zeros(located.shape[0], bool)
    candidates = []
    for seed in order:
        if used[seed]:
            continue
        near = np.flatnonzero(~used & (np.hypot(*(located[:, :2] - located[seed, :2]).T) < radius_m))
        # one point per pose: the nearest to the seed
        best = {}
        for k in near:
            pose_index = int(located[k, 2])
            d = float(np.hypot(*(located[k, :2] - located[seed, :2])))
            if pose_index not in best or d < best[pose_index][0]:
                best[pose_index] = (d, k)
        members = [k for _, k in best.values()]
        pose_indices = sorted(best)
        span = 0.0
        if len(pose_indices) > 1:
            p = positions[pose_indices]
            span = float(np.max(np.hypot(*(p[:, None, :] - p[None, :, :]).transpose(2, 0, 1))))
        if len(pose_indices) >= min_poses and span >= min_span_m:
            pts = located[members, :2]
            centre = np.median(pts, axis=0)
            candidates.append(CornerCandidate(
                point_m=centre,
                spread_m=float(np.sqrt(np.mean(np.sum((pts - centre) ** 2, axis=1)))),
                pose_indices=pose_indices, travel_span_m=span,
                power=float(np.median(located[members, 3]))))
            used[near] = True
        else:
            used[seed] = True
    return candidates
