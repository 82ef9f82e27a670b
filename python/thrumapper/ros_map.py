#
# SPDX-License-Identifier: GPL-3.0-or-later
#
"""A map as a ROS map_server occupancy grid: PREFIX.pgm and PREFIX.yaml.

The grid follows map_server's conventions: an 8-bit binary PGM (P5) whose first row is the
top of the map (largest y), `origin` the world position of the bottom-left pixel, `negate: 0`,
so a pixel value v means occupancy p = (255 − v)/255: occupied (p > occupied_thresh = 0.65)
is 0, free (p < free_thresh = 0.196) is 254, unknown is 205.

Occupied: the mapped walls (the face LineStrings, drawn one pixel wide plus the pixels the
wall's face touches) and the corners. Free: the cells the radar saw across before an echo, from
each pose's RX array centre to every reflection point behind the map, up to the first wall:
the corridor is free, a room seen only through its wall stays unknown.
"""

import math
import os

import numpy as np

OCCUPIED, FREE, UNKNOWN = 0, 254, 205


def _cells(p0, p1, origin, resolution_m, shape):
    """Grid cells (row, col) along the segment p0→p1 (sampled at a quarter pixel)."""
    length = float(np.hypot(*(np.asarray(p1) - np.asarray(p0))))
    count = max(2, int(math.ceil(4.0 * length / resolution_m)) + 1)
    t = np.linspace(0.0, 1.0, count)
    pts = np.asarray(p0)[None, :] + t[:, None] * (np.asarray(p1) - np.asarray(p0))[None, :]
    col = np.floor((pts[:, 0] - origin[0]) / resolution_m).astype(int)
    row_from_bottom = np.floor((pts[:, 1] - origin[1]) / resolution_m).astype(int)
    row = shape[0] - 1 - row_from_bottom
    ok = (row >= 0) & (row < shape[0]) & (col >= 0) & (col < shape[1])
    return row[ok], col[ok]


def occupancy_grid(fused, resolution_m=0.05, margin_m=1.0):
    """(grid uint8 (rows, cols), origin [x, y]) of a FusedMap."""
    if not resolution_m > 0:
        raise ValueError(f"resolution_m: expected > 0, got {resolution_m}")
    points = [np.zeros((0, 2))]
    points += [np.vstack((w.start_m, w.end_m)) for w in fused.walls]
    points += [c.position_m[None, :] for c in fused.corners]
    if len(fused.trajectory):
        points.append(fused.trajectory[:, :2])
    points += [e for e in fused.echoes.values() if len(e)]
    allp = np.vstack(points)
    if allp.shape[0] == 0:
        allp = np.zeros((1, 2))
    lo = np.floor((allp.min(axis=0) - margin_m) / resolution_m) * resolution_m
    hi = np.ceil((allp.max(axis=0) + margin_m) / resolution_m) * resolution_m
    cols = int(round((hi[0] - lo[0]) / resolution_m))
    rows = int(round((hi[1] - lo[1]) / resolution_m))
    grid = np.full((rows, cols), UNKNOWN, np.uint8)
    shape = grid.shape
    # free space: rays from the robot to each line-of-sight echo (stopping short of the wall)
    los = fused.echoes.get("line_of_sight", np.zeros((0, 2)))
    hid = fused.echoes.get("hidden", np.zeros((0, 2)))
    if len(fused.trajectory) and (len(los) or len(hid)):
        robots = fused.trajectory[:, :2]
        for target in los:
            start = robots[int(np.argmin(np.hypot(*(robots - target).T)))]
            direction = target - start
            length = float(np.hypot(*direction))
            if length <= 2 * resolution_m:
                continue
            end = start + direction * (1.0 - 2 * resolution_m / length)
            r, c = _cells(start, end, lo, resolution_m, shape)
            grid[r, c] = FREE
    for p in (fused.trajectory[:, :2] if len(fused.trajectory) else []):
        r, c = _cells(p, p, lo, resolution_m, shape)
        grid[r, c] = FREE
    for w in fused.walls:
        r, c = _cells(w.start_m, w.end_m, lo, resolution_m, shape)
        grid[r, c] = OCCUPIED
    for corner in fused.corners:
        r, c = _cells(corner.position_m, corner.position_m, lo, resolution_m, shape)
        grid[r, c] = OCCUPIED
    return grid, lo


def write_ros_map(fused, prefix, resolution_m=0.05):
    """Write PREFIX.pgm and PREFIX.yaml; returns their paths."""
    grid, origin = occupancy_grid(fused, resolution_m)
    pgm = prefix + ".pgm"
    yml = prefix + ".yaml"
    with open(pgm, "wb") as handle:
        handle.write(f"P5\n# thrumapper map, {resolution_m} m/pixel\n{grid.shape[1]} {grid.shape[0]}\n255\n".encode("ascii"))
        handle.write(grid.tobytes())
    with open(yml, "w", encoding="utf-8") as handle:
        handle.write(f"image: {os.path.basename(pgm)}\n")
        handle.write(f"resolution: {resolution_m}\n")
        handle.write(f"origin: [{origin[0]:.4f}, {origin[1]:.4f}, 0.0]\n")
        handle.write("negate: 0\noccupied_thresh: 0.65\nfree_thresh: 0.196\nmode: trinary\n")
    return pgm, yml


def read_pgm(path):
    """A binary PGM as a uint8 array (for checks and tests)."""
    with open(path, "rb") as handle:
        data = handle.read()
    fields, pos = [], 0
    while len(fields) < 4:
        while data[pos:pos + 1].isspace():
            pos += 1
        if data[pos:pos + 1] == b"#":
            pos = data.index(b"\n", pos) + 1
            continue
        end = pos
        while not data[end:end + 1].isspace():
            end += 1
        fields.append(data[pos:end])
        pos = end
    if fields[0] != b"P5":
        raise ValueError(f"{path}: not a binary PGM (magic {fields[0]!r})")
    width, height, maxval = int(fields[1]), int(fields[2]), int(fields[3])
    pos += 1
    pixels = np.frombuffer(data[pos:pos + width * height], np.uint8)
    if pixels.size != width * height or maxval != 255:
        raise ValueError(f"{path}: truncated or not 8-bit")
    return pixels.reshape(height, width)
