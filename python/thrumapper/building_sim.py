#
# SPDX-License-Identifier: GPL-3.0-or-later
#
"""The simulated building: the wideband, near-field MIMO channel of FORMATS.md.

    H[f, m, n] = β_m(f_n) · Σ_k w_k · α_k(f_n) · Σ_p g_p · exp(−j2π f_n (τ_{p,k,m} + τ_sys)) + noise

Every path is traced for every (TX element k, RX element m) pair with its exact spherical
length, and evaluated at every subcarrier's absolute frequency f_n = fc + Δf_n:

- direct coupling TX→RX (free space, through any wall in between);
- first-order specular reflections off every wall face, by the image method: the TX element
  is mirrored in the face that looks at it, and the path exists when the specular point lies
  on the face's extent (door gaps are holes in the face);
- second-order reflections (two faces): dihedral corners' retro-reflection, corridor
  double bounces;
- point scatterers: a seeded set of weak diffuse scatterers along every face, edge scatterers
  at free wall ends and door frames, and the scene's clutter;
- transmission through every wall that a leg of a path crosses.

Walls are layered dielectric slabs (or perfect conductors). Their TE reflection and insertion
transmission coefficients come from the characteristic (transfer) matrix of the layer stack,
which includes every internal multiple reflection, at the actual incidence angle and frequency.

Gains are those of free-space propagation between isotropic elements: λ/(4π·L) for a path
with unfolded length L (direct, specular: image method), times the reflection and
transmission coefficients, and λ/(4π)·a/(d1·d2) for a point scatterer of scattering amplitude
a = √(σ/4π) (the bistatic radar equation in amplitude). H is therefore dimensionless:
|H| = 1 would be a lossless link. docs/simulator.md has the details and the simplifications.
"""

import datetime as _dt
import math
import time
from dataclasses import dataclass, field

import numpy as np

from . import scene as _scene

SPEED_OF_LIGHT_M_S = _scene.SPEED_OF_LIGHT_M_S

# Kinds of point scatterer.
SCATTER_DIFFUSE, SCATTER_EDGE, SCATTER_CLUTTER = 0, 1, 2

# Numerical slack for "strictly in front of a face", metres.
_EPS_M = 1e-9


# ----------------------------------------------------------------------------------------
# Wall materials: TE reflection and transmission of a layered slab
# ----------------------------------------------------------------------------------------
def slab_coefficients(material, cos_theta, frequencies_hz):
    """TE (E perpendicular to the plane of incidence) coefficients of a wall, shape (..., N).

    Returns (reflection, transmission). Both are field ratios of plane waves:
    - reflection Γ is referenced to the front face (the image method mirrors in that face);
    - transmission is the *insertion* coefficient: the field behind the wall relative to the
      field the same straight ray would have without the wall, so a path's geometric length
      keeps its free-space phase and the wall adds its own phase and extra delay.

    The characteristic-matrix method (Macleod, Thin-Film Optical Filters, §2) gives the exact
    stack response, every internal multiple reflection included: for one layer it is the
    Fabry–Perot closed form Γ = r(1 − e^{−2jδ}) / (1 − r² e^{−2jδ}).
    cos_theta: cosine of the incidence angle from the wall normal, any shape.
    """
    # 1e-6 keeps 1 - sin²θ representable at grazing incidence (θ = 89.99994°).
    cos_t = np.clip(np.asarray(cos_theta, dtype=float), 1e-6, 1.0)[..., None]
    f_hz = np.asarray(frequencies_hz, dtype=float)
    shape = np.broadcast_shapes(cos_t.shape, f_hz.shape)
    if material.conductor:
        return -np.ones(shape, dtype=complex), np.zeros(shape, dtype=complex)
    k0 = 2.0 * np.pi * f_hz / SPEED_OF_LIGHT_M_S
    sin2 = 1.0 - cos_t**2
    eta0 = cos_t.astype(complex)  # tilted admittance of air for TE, in units of Y0
    m11 = np.ones(shape, dtype=complex)
    m12 = np.zeros(shape, dtype=complex)
    m21 = np.zeros(shape, dtype=complex)
    m22 = np.ones(shape, dtype=complex)
    for eps, thickness_m in material.layers:
        # Principal root: Im ≤ 0 for a lossy layer, so e^{−jδ} decays (e^{+jωt} convention).
        eta = np.sqrt(complex(eps) - sin2)
        delta = k0 * thickness_m * eta
        c, s = np.cos(delta), np.sin(delta)
        l11, l12, l21, l22 = c, 1j * s / eta, 1j * eta * s, c
        m11, m12, m21, m22 = (m11 * l11 + m12 * l21, m11 * l12 + m12 * l22,
                              m21 * l11 + m22 * l21, m21 * l12 + m22 * l22)
    b = m11 + m12 * eta0  # [B, C] = M · [1, η_substrate], the substrate being air again
    c_ = m21 + m22 * eta0
    denominator = eta0 * b + c_
    reflection = (eta0 * b - c_) / denominator
    transmission = 2.0 * eta0 / denominator
    # Remove the free-space phase across the wall's thickness that the straight ray already has.
    transmission = transmission * np.exp(1j * k0 * material.thickness_m * cos_t)
    return reflection, transmission


# Incidence-angle grid of the coefficient tables: 2049 points over 0–90° (0.044° apart), where
# linear interpolation of Γ and T is good to ~1e-7, far below anything a radar resolves.
_TABLE_POINTS = 2049


def coefficient_table(material, frequencies_hz):
    """(Γ, T) of a material over the incidence grid at these frequencies: (2, _TABLE_POINTS, N),
    for interpolate_coefficients."""
    theta = np.linspace(0.0, np.pi / 2, _TABLE_POINTS)
    return np.stack(slab_coefficients(material, np.cos(theta), frequencies_hz))


def interpolate_coefficients(table, cos_theta):
    """One of coefficient_table's tables (Γ or T, (_TABLE_POINTS, N)) at these incidence
    cosines, any shape: (..., N), linear in the incidence angle."""
    position = np.arccos(np.clip(np.asarray(cos_theta, float), 0.0, 1.0)) * ((_TABLE_POINTS - 1) / (np.pi / 2))
    index = np.minimum(position.astype(int), _TABLE_POINTS - 2)
    frac = (position - index)[..., None]
    lo = table[index]
    return lo + frac * (table[index + 1] - lo)


def _coefficient_table(geom, material_id, frequencies_hz):
    """coefficient_table of one of the scene's materials, cached."""
    frequencies_hz = np.asarray(frequencies_hz, dtype=float)
    key = (int(material_id), frequencies_hz.tobytes())
    table = geom.coefficient_tables.get(key)
    if table is None:
        table = coefficient_table(geom.materials[material_id], frequencies_hz)
        if len(geom.coefficient_tables) > 64:  # many frequency sets (a sweep): start afresh
            geom.coefficient_tables.clear()
        geom.coefficient_tables[key] = table
    return table


def _wall_coefficients(geom, material_of, cos_theta, frequencies_hz, which):
    """Γ (which=0) or T (which=1) for rows of (material index, cos θ): (rows, N)."""
    out = np.empty((cos_theta.size, np.size(frequencies_hz)), dtype=complex)
    for material_id in np.unique(material_of):
        rows = np.flatnonzero(material_of == material_id)
        out[rows] = interpolate_coefficients(_coefficient_table(geom, material_id, frequencies_hz)[which],
                                             cos_theta[rows])
    return out


# ----------------------------------------------------------------------------------------
# Building geometry: solid wall pieces, their faces, junctions, corners and scatterers
# ----------------------------------------------------------------------------------------
@dataclass(eq=False)
class BuildingGeometry:
    """Walls cut by their doors into solid pieces, with everything the tracer needs.

    Piece arrays are indexed by piece p. The face of side s (0: the +normal side, 1: the
    −normal side) lies at signed distance ±half_thickness_m from the centre line and spans
    face_extent_m[p, s] = (start, end), metres along the piece's direction from start_m.
    """

    start_m: np.ndarray  # (P, 2) centre-line start
    end_m: np.ndarray  # (P, 2)
    direction: np.ndarray  # (P, 2) unit vector start → end
    normal: np.ndarray  # (P, 2) unit left normal
    length_m: np.ndarray  # (P,)
    half_thickness_m: np.ndarray  # (P,)
    wall_index: np.ndarray  # (P,) index into scene.walls
    material_index: np.ndarray  # (P,) index into materials
    door: np.ndarray  # (P,) bool: the piece is a closed door's leaf
    materials: list
    face_extent_m: np.ndarray  # (P, 2, 2)
    junction: np.ndarray  # (P, 2) bool: the piece's start / end abuts another wall
    corners: list  # dicts: position_m, pieces (i, j), normals ((2,), (2,)), corner_type
    scatter_position_m: np.ndarray  # (S, 2)
    scatter_normal: np.ndarray  # (S, 2): outward face normal (diffuse), zero (isotropic)
    scatter_amplitude_m: np.ndarray  # (S,) complex scattering amplitude √(σ/4π)·e^{jφ}
    scatter_piece: np.ndarray  # (S,) piece the scatterer sits on, -1 for clutter
    scatter_kind: np.ndarray  # (S,) SCATTER_*
    scatter_name: list = field(default_factory=list)  # (S,) labels for the path truth
    coefficient_tables: dict = field(default_factory=dict)  # (material, frequencies) → (Γ, T) tables

    @property
    def num_pieces(self):
        return self.start_m.shape[0]

    def face_points(self, piece, side, along_m):
        """World points at along_m metres along the face (piece, side)."""
        sign = 1.0 if side == 0 else -1.0
        return (self.start_m[piece] + np.multiply.outer(along_m, self.direction[piece])
                + sign * self.half_thickness_m[piece] * self.normal[piece])


def _cross(a, b):
    return a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]


def building_geometry(scene):
    """The scene's BuildingGeometry, computed once and cached on the scene (walls, doors,
    clutter, seed and physics are read then: load the scene again after changing them)."""
    cached = getattr(scene, "_building_geometry", None)
    if cached is not None:
        return cached
    geom = _build_geometry(scene)
    scene._building_geometry = geom
    return geom


def _build_geometry(scene):
    materials, material_ids = [], {}

    def material_id(material):
        if id(material) not in material_ids:
            material_ids[id(material)] = len(materials)
            materials.append(material)
        return material_ids[id(material)]

    starts, ends, wall_of, material_of, is_door = [], [], [], [], []
    for wall in scene.walls:
        length = wall.length_m
        direction = (wall.end_m - wall.start_m) / length
        doors = sorted((d for d in scene.doors if d.wall_index == wall.index), key=lambda d: d.position_m)
        cursor = 0.0
        solid = []  # (start, end, material, door?) along the wall
        for door in doors:
            gap_start, gap_end = door.position_m - door.width_m / 2, door.position_m + door.width_m / 2
            solid.append((cursor, gap_start, wall.material, False))
            if door.material is not None:  # a closed door: a leaf of its own material in the gap
                solid.append((gap_start, gap_end, door.material, True))
            cursor = gap_end
        solid.append((cursor, length, wall.material, False))
        for a, b, material, door_leaf in solid:
            if b - a > 1e-3:  # a door flush with a wall end leaves no piece
                starts.append(wall.start_m + a * direction)
                ends.append(wall.start_m + b * direction)
                wall_of.append(wall.index)
                material_of.append(material_id(material))
                is_door.append(door_leaf)
    count = len(starts)
    start = np.array(starts, dtype=float).reshape(count, 2)
    end = np.array(ends, dtype=float).reshape(count, 2)
    vec = end - start
    length = np.hypot(vec[:, 0], vec[:, 1])
    direction = vec / np.maximum(length, 1e-12)[:, None]
    normal = np.column_stack((-direction[:, 1], direction[:, 0]))
    half = np.array([materials[i].thickness_m / 2 for i in material_of], dtype=float)
    wall_index = np.array(wall_of, dtype=int)
    material_index = np.array(material_of, dtype=int)
    door = np.array(is_door, dtype=bool)

    extent = np.zeros((count, 2, 2))
    extent[:, :, 1] = length[:, None]
    junction = np.zeros((count, 2), dtype=bool)
    corners = []
    for i in range(count):
        for end_index in (0, 1):
            point = start[i] if end_index == 0 else end[i]
            j, x_point = _find_junction(i, point, start, direction, length, half, wall_index)
            if j < 0:
                continue
            junction[i, end_index] = True
            along_x_j = (x_point - start[j]) @ direction[j]
            # Which ways the other wall runs on from the junction point.
            ways = []
            if along_x_j < length[j] - half[i] - 1e-6:
                ways.append(direction[j])
            if along_x_j > half[i] + 1e-6:
                ways.append(-direction[j])
            for side, sign in ((0, 1.0), (1, -1.0)):
                face_origin = start[i] + sign * half[i] * normal[i]
                un = direction[i] @ normal[j]
                # Where this face's line meets the other wall's two faces.
                t = np.array([(s_j * half[j] - (face_origin - start[j]) @ normal[j]) / un for s_j in (1.0, -1.0)])
                inner = any(sign * (w @ normal[i]) > 1e-6 for w in ways)
                # An inner face stops at the other wall's near face; an outer face wraps round
                # to its far face.
                if end_index == 0:
                    stop = t.max() if inner else t.min()
                else:
                    stop = t.min() if inner else t.max()
                extent[i, side, end_index] = stop
                position = face_origin + stop * direction[i]
                corners.append({
                    "position_m": position,
                    "pieces": (i, j),
                    "corner_type": "concave" if inner else "convex",
                })
    corners = _dedupe_corners(corners, start, normal, direction, half)

    geom = BuildingGeometry(
        start_m=start, end_m=end, direction=direction, normal=normal, length_m=length, half_thickness_m=half,
        wall_index=wall_index, material_index=material_index, door=door, materials=materials, face_extent_m=extent,
        junction=junction, corners=corners,
        scatter_position_m=np.zeros((0, 2)), scatter_normal=np.zeros((0, 2)),
        scatter_amplitude_m=np.zeros(0, dtype=complex), scatter_piece=np.zeros(0, dtype=int),
        scatter_kind=np.zeros(0, dtype=int),
    )
    _add_scatterers(geom, scene)
    return geom


def _find_junction(i, point, start, direction, length, half, wall_index):
    """The wall piece that the end `point` of piece i abuts: (j, centre-line crossing) or (-1, None)."""
    best, best_distance, best_x = -1, np.inf, None
    for j in range(start.shape[0]):
        if wall_index[j] == wall_index[i] or abs(_cross(direction[i], direction[j])) < 0.1:
            continue
        rel = point - start[j]
        along = np.clip(rel @ direction[j], 0.0, length[j])
        distance = np.hypot(*(rel - along * direction[j]))
        # A centre line drawn to the other wall's centre, or only to its face, both count.
        if distance <= half[j] + 0.02 and distance < best_distance:
            # The crossing of the two centre lines.
            s = _cross(start[j] - start[i], direction[j]) / _cross(direction[i], direction[j])
            best, best_distance, best_x = j, distance, start[i] + s * direction[i]
    return best, best_x


def _dedupe_corners(corners, start, normal, direction, half):
    """Merge the corners found from both walls of an L, and attach the two face normals."""
    merged = []
    for corner in corners:
        if any(np.hypot(*(corner["position_m"] - other["position_m"])) < 0.02 for other in merged):
            continue
        i, j = corner["pieces"]
        p = corner["position_m"]
        # The outward normal of the face of each piece that the corner lies on.
        normals = tuple(np.sign((p - start[q]) @ normal[q]) * normal[q] for q in (i, j))
        merged.append({**corner, "normals": normals})
    return merged


def _add_scatterers(geom, scene):
    """Diffuse scatterers along every face, edge scatterers at free ends, and the clutter."""
    physics = scene.physics
    rng = _scene.rng_for(scene.seed, _scene.RNG_DIFFUSE)
    positions, normals, amplitudes, pieces, kinds, names = [], [], [], [], [], []
    fc = scene.radar.carrier_hz
    for p in range(geom.num_pieces):
        material = geom.materials[geom.material_index[p]]
        # A surface scatters in proportion to how strongly the material reflects.
        gamma2 = float(np.abs(slab_coefficients(material, 1.0, fc)[0]).ravel()[0] ** 2)
        for side, sign in ((0, 1.0), (1, -1.0)):
            a0, a1 = geom.face_extent_m[p, side]
            count = rng.poisson(physics["diffuse_density_per_m"] * max(a1 - a0, 0.0))
            along = rng.uniform(a0, a1, count)
            rcs = rng.exponential(physics["diffuse_rcs_m2"], count) * gamma2
            phase = rng.uniform(0.0, 2.0 * np.pi, count)
            if not physics["diffuse"]:
                continue  # drawn anyway: switching diffuse off leaves the other draws alone
            positions.append(geom.face_points(p, side, along).reshape(-1, 2))
            normals.append(np.tile(sign * geom.normal[p], (count, 1)))
            amplitudes.append(np.sqrt(rcs / (4.0 * np.pi)) * np.exp(1j * phase))
            pieces.append(np.full(count, p))
            kinds.append(np.full(count, SCATTER_DIFFUSE))
            names.extend([f"diffuse:{scene.walls[geom.wall_index[p]].name}"] * count)
        for end_index in (0, 1):
            phase = rng.uniform(0.0, 2.0 * np.pi)
            if geom.junction[p, end_index] or not physics["edges"]:
                continue
            point = geom.start_m[p] if end_index == 0 else geom.end_m[p]
            positions.append(point[None, :])
            normals.append(np.zeros((1, 2)))
            rcs = physics["edge_rcs_m2"] * gamma2
            amplitudes.append(np.array([math.sqrt(rcs / (4.0 * np.pi)) * np.exp(1j * phase)]))
            pieces.append(np.array([p]))
            kinds.append(np.array([SCATTER_EDGE]))
            names.append(f"edge:{scene.walls[geom.wall_index[p]].name}:{'start' if end_index == 0 else 'end'}")
    if physics["clutter"] and len(scene.clutter_names):
        positions.append(scene.clutter_position_m)
        normals.append(np.zeros_like(scene.clutter_position_m))
        amplitudes.append(scene.clutter_amplitude_m)
        pieces.append(np.full(len(scene.clutter_names), -1))
        kinds.append(np.full(len(scene.clutter_names), SCATTER_CLUTTER))
        names.extend(scene.clutter_names)
    if positions:
        geom.scatter_position_m = np.vstack(positions)
        geom.scatter_normal = np.vstack(normals)
        geom.scatter_amplitude_m = np.concatenate(amplitudes)
        geom.scatter_piece = np.concatenate(pieces).astype(int)
        geom.scatter_kind = np.concatenate(kinds).astype(int)
        geom.scatter_name = names


# ----------------------------------------------------------------------------------------
# Ray legs: which walls a straight segment crosses, and what they do to it
# ----------------------------------------------------------------------------------------
def _crossings(geom, p0, p1, exclude_a=None, exclude_b=None):
    """The (leg, piece) pairs where segment p0→p1 crosses a piece's centre line.

    p0, p1: (L, 2). exclude_a/b: (L,) piece indices a leg may touch (its bounce points), or -1.
    Returns (leg indices, piece indices, cos of the incidence angle at the crossing).
    """
    count = p0.shape[0]
    if count == 0 or geom.num_pieces == 0:
        empty = np.zeros(0, dtype=int)
        return empty, empty, np.zeros(0)
    d = p1 - p0  # (L, 2)
    e = geom.end_m - geom.start_m  # (P, 2)
    r = geom.start_m[None, :, :] - p0[:, None, :]  # (L, P, 2)
    denominator = _cross(d[:, None, :], e[None, :, :])  # (L, P)
    parallel = np.abs(denominator) < 1e-15
    safe = np.where(parallel, 1.0, denominator)
    t = _cross(r, e[None, :, :]) / safe  # along the leg
    s = _cross(r, d[:, None, :]) / safe  # along the piece
    hit = ~parallel & (t > 1e-9) & (t < 1.0 - 1e-9) & (s >= 0.0) & (s <= 1.0)
    pieces = np.arange(geom.num_pieces)[None, :]
    if exclude_a is not None:
        hit &= pieces != exclude_a[:, None]
    if exclude_b is not None:
        hit &= pieces != exclude_b[:, None]
    legs, hit_pieces = np.nonzero(hit)
    leg_length = np.hypot(d[legs, 0], d[legs, 1])
    cos_theta = np.abs(np.einsum("ij,ij->i", d[legs], geom.normal[hit_pieces])) / np.maximum(leg_length, 1e-12)
    return legs, hit_pieces, cos_theta


def _leg_transmission(geom, physics, p0, p1, frequencies_hz, exclude_a=None, exclude_b=None):
    """Product of the insertion transmission coefficients of every wall a leg crosses.

    Returns (factor (L, N) complex, or None when no leg crosses anything; crossings (L,)).
    A leg crossing more than physics["max_walls_crossed"] walls, or any wall when
    transmission is off (opaque walls), gets factor 0.
    """
    count = p0.shape[0]
    legs, pieces, cos_theta = _crossings(geom, p0, p1, exclude_a, exclude_b)
    crossings = np.bincount(legs, minlength=count)
    if legs.size == 0:
        return None, crossings
    factor = np.ones((count, np.size(frequencies_hz)), dtype=complex)
    if not physics["transmission"]:
        factor[crossings > 0] = 0.0
        return factor, crossings
    coefficient = _wall_coefficients(geom, geom.material_index[pieces], cos_theta, frequencies_hz, 1)
    # legs is sorted (np.nonzero order); a leg crossing several walls takes one per round, so
    # that no round indexes a leg twice.
    rank = np.arange(legs.size) - np.searchsorted(legs, legs, side="left")
    for r in range(int(rank.max()) + 1):
        rows = np.flatnonzero(rank == r)
        factor[legs[rows]] *= coefficient[rows]
    factor[crossings > physics["max_walls_crossed"]] = 0.0
    return factor, crossings


def _apply(factor, values):
    return values if factor is None else values * factor


# ----------------------------------------------------------------------------------------
# Path tracing for one pose
# ----------------------------------------------------------------------------------------
@dataclass(eq=False)
class _Paths:
    """Specular paths, one row per (path, k, m) that exists."""

    kind: str
    k: np.ndarray  # (V,)
    m: np.ndarray  # (V,)
    length_m: np.ndarray  # (V,) unfolded length
    gain: np.ndarray  # (V, N) everything but e^{−j2πfL/c}: λ/(4πL)·Γ·T
    pieces: np.ndarray  # (V, 2) bounce pieces, -1 where none
    points: np.ndarray  # (V, 2, 2) bounce points, NaN where none
    crossings: np.ndarray  # (V,) walls crossed by the path's legs


def _coefficients_by_material(geom, piece, cos_theta, frequencies_hz):
    """Γ of the face of `piece` at each row's incidence, (V, N)."""
    return _wall_coefficients(geom, geom.material_index[piece], cos_theta, frequencies_hz, 0)


def _direct_paths(geom, physics, tx, rx, frequencies_hz):
    num_tx, num_rx = tx.shape[0], rx.shape[0]
    k, m = np.meshgrid(np.arange(num_tx), np.arange(num_rx), indexing="ij")
    k, m = k.ravel(), m.ravel()
    p0, p1 = tx[k], rx[m]
    length = np.hypot(*(p1 - p0).T)
    lam = SPEED_OF_LIGHT_M_S / np.asarray(frequencies_hz)
    gain = lam[None, :] / (4.0 * np.pi * length[:, None])
    factor, crossings = _leg_transmission(geom, physics, p0, p1, frequencies_hz)
    return _Paths("direct", k, m, length, _apply(factor, gain), np.full((k.size, 2), -1),
                  np.full((k.size, 2, 2), np.nan), crossings)


def _local(geom, points):
    """Points in every piece's frame: (along, signed normal) each (P, L)."""
    rel = points[None, :, :] - geom.start_m[:, None, :]
    return np.einsum("pld,pd->pl", rel, geom.direction), np.einsum("pld,pd->pl", rel, geom.normal)


def _first_order_paths(geom, physics, tx, rx, frequencies_hz, robot_xy):
    """Specular reflections off one face, by the image method, for every (piece, k, m)."""
    if geom.num_pieces == 0:
        return None
    half = geom.half_thickness_m
    along_t, z_t = _local(geom, tx)  # (P, K)
    along_r, z_r = _local(geom, rx)  # (P, M)
    side_t = np.where(z_t >= 0.0, 1.0, -1.0)
    d_t = np.abs(z_t) - half[:, None]  # TX height above the face that looks at it
    d_r = z_r[:, None, :] * side_t[:, :, None] - half[:, None, None]  # RX above the same face, (P, K, M)
    valid = (d_t[:, :, None] > _EPS_M) & (d_r > _EPS_M)
    total_depth = d_t[:, :, None] + d_r
    t = d_t[:, :, None] / np.where(valid, total_depth, 1.0)
    along_q = along_t[:, :, None] + t * (along_r[:, None, :] - along_t[:, :, None])
    side_index = (side_t < 0).astype(int)  # (P, K)
    extent = geom.face_extent_m[np.arange(geom.num_pieces)[:, None], side_index]  # (P, K, 2)
    valid &= (along_q >= extent[:, :, None, 0]) & (along_q <= extent[:, :, None, 1])
    # Faces beyond range contribute nothing measurable; skip their legs.
    valid &= _piece_distance(geom, robot_xy)[:, None, None] <= physics["max_range_m"]
    p, k, m = np.nonzero(valid)
    if p.size == 0:
        return None
    length = np.hypot(along_r[p, m] - along_t[p, k], total_depth[p, k, m])
    cos_theta = total_depth[p, k, m] / length
    q = (geom.start_m[p] + along_q[p, k, m][:, None] * geom.direction[p]
         + (side_t[p, k] * half[p])[:, None] * geom.normal[p])
    lam = SPEED_OF_LIGHT_M_S / np.asarray(frequencies_hz)
    gain = lam[None, :] / (4.0 * np.pi * length[:, None]) * _coefficients_by_material(geom, p, cos_theta, frequencies_hz)
    f1, c1 = _leg_transmission(geom, physics, tx[k], q, frequencies_hz, exclude_a=p)
    f2, c2 = _leg_transmission(geom, physics, q, rx[m], frequencies_hz, exclude_a=p)
    gain = _apply(f2, _apply(f1, gain))
    pieces = np.column_stack((p, np.full(p.size, -1)))
    points = np.full((p.size, 2, 2), np.nan)
    points[:, 0] = q
    return _Paths("wall", k, m, length, gain, pieces, points, c1 + c2)


def _piece_distance(geom, point):
    """Distance from a point to every piece's centre-line segment, (P,)."""
    rel = point[None, :] - geom.start_m
    along = np.clip(np.einsum("pd,pd->p", rel, geom.direction), 0.0, geom.length_m)
    return np.hypot(*(rel - along[:, None] * geom.direction).T)


def _second_order_paths(geom, physics, tx, rx, frequencies_hz, robot_xy):
    """TX → face a → face b → RX for every ordered pair of pieces, by double imaging."""
    count = geom.num_pieces
    if count < 2:
        return None
    half = geom.half_thickness_m
    along_t, z_t = _local(geom, tx)  # (P, K)
    along_r, z_r = _local(geom, rx)  # (P, M)
    side_t = np.where(z_t >= 0.0, 1.0, -1.0)
    side_r = np.where(z_r >= 0.0, 1.0, -1.0)
    d_t = np.abs(z_t) - half[:, None]
    d_r = np.abs(z_r) - half[:, None]
    in_range = _piece_distance(geom, robot_xy) <= physics["max_range_m"]
    usable_a = np.any(d_t > _EPS_M, axis=1) & in_range
    usable_b = np.any(d_r > _EPS_M, axis=1) & in_range
    a_idx, b_idx = np.nonzero(usable_a[:, None] & usable_b[None, :] & ~np.eye(count, dtype=bool))
    if a_idx.size == 0:
        return None
    # First image: each TX element mirrored in the face of a that looks at it, (C, K, 2).
    image1 = tx[None, :, :] - (2.0 * side_t[a_idx] * d_t[a_idx])[:, :, None] * geom.normal[a_idx][:, None, :]
    rel_b = image1 - geom.start_m[b_idx][:, None, :]
    along_i_b = np.einsum("ckd,cd->ck", rel_b, geom.direction[b_idx])
    z_i_b = np.einsum("ckd,cd->ck", rel_b, geom.normal[b_idx])
    sr = side_r[b_idx]  # (C, M): face of b that looks at the RX element
    d_i_b = z_i_b[:, :, None] * sr[:, None, :] - half[b_idx][:, None, None]  # (C, K, M)
    d_r_b = d_r[b_idx][:, None, :]  # (C, 1, M)
    valid = (d_t[a_idx][:, :, None] > _EPS_M) & (d_r_b > _EPS_M) & (d_i_b > _EPS_M)
    depth_b = d_i_b + d_r_b
    t_b = d_i_b / np.where(valid, depth_b, 1.0)
    along_r_b = along_r[b_idx][:, None, :]
    along_qb = along_i_b[:, :, None] + t_b * (along_r_b - along_i_b[:, :, None])
    extent_b = geom.face_extent_m[b_idx[:, None], (sr < 0).astype(int)]  # (C, M, 2)
    valid &= (along_qb >= extent_b[:, None, :, 0]) & (along_qb <= extent_b[:, None, :, 1])
    c, k, m = np.nonzero(valid)
    if c.size == 0:
        return None
    a, b = a_idx[c], b_idx[c]
    length = np.hypot(along_r[b, m] - along_i_b[c, k], depth_b[c, k, m])
    cos_b = depth_b[c, k, m] / length
    q_b = (geom.start_m[b] + along_qb[c, k, m][:, None] * geom.direction[b]
           + (side_r[b, m] * half[b])[:, None] * geom.normal[b])
    # Second bounce point: where image1 → q_b meets the face of a.
    rel_qa = q_b - geom.start_m[a]
    along_qb_a = np.einsum("vd,vd->v", rel_qa, geom.direction[a])
    d_qb_a = np.einsum("vd,vd->v", rel_qa, geom.normal[a]) * side_t[a, k] - half[a]
    ok = d_qb_a > _EPS_M
    depth_a = d_t[a, k] + d_qb_a
    t_a = d_t[a, k] / np.where(ok, depth_a, 1.0)
    along_qa = along_t[a, k] + t_a * (along_qb_a - along_t[a, k])
    extent_a = geom.face_extent_m[a, (side_t[a, k] < 0).astype(int)]
    ok &= (along_qa >= extent_a[:, 0]) & (along_qa <= extent_a[:, 1])
    q_a = geom.start_m[a] + along_qa[:, None] * geom.direction[a] + (side_t[a, k] * half[a])[:, None] * geom.normal[a]
    # The middle leg leaves a toward b's reflecting side.
    ok &= np.einsum("vd,vd->v", q_a - geom.start_m[b], geom.normal[b]) * side_r[b, m] - half[b] > _EPS_M
    if not np.any(ok):
        return None
    a, b, k, m = a[ok], b[ok], k[ok], m[ok]
    length, cos_b, q_a, q_b = length[ok], cos_b[ok], q_a[ok], q_b[ok]
    cos_a = depth_a[ok] / np.hypot(along_qb_a[ok] - along_t[a, k], depth_a[ok])
    lam = SPEED_OF_LIGHT_M_S / np.asarray(frequencies_hz)
    gain = (lam[None, :] / (4.0 * np.pi * length[:, None])
            * _coefficients_by_material(geom, a, cos_a, frequencies_hz)
            * _coefficients_by_material(geom, b, cos_b, frequencies_hz))
    f1, c1 = _leg_transmission(geom, physics, tx[k], q_a, frequencies_hz, exclude_a=a)
    f2, c2 = _leg_transmission(geom, physics, q_a, q_b, frequencies_hz, exclude_a=a, exclude_b=b)
    f3, c3 = _leg_transmission(geom, physics, q_b, rx[m], frequencies_hz, exclude_a=b)
    gain = _apply(f3, _apply(f2, _apply(f1, gain)))
    points = np.stack((q_a, q_b), axis=1)
    return _Paths("double", k, m, length, gain, np.column_stack((a, b)), points, c1 + c2 + c3)


def _scatter_legs(geom, physics, elements, frequencies_hz, select):
    """One leg per (scatterer, element) for the selected scatterers.

    Returns (distance (S, E), radiation pattern amplitude (S, E), wall transmission (S, E, N)
    or None when no leg crosses a wall, walls crossed (S, E)).
    """
    pos = geom.scatter_position_m[select]
    normal = geom.scatter_normal[select]
    piece = geom.scatter_piece[select]
    count, num_el = pos.shape[0], elements.shape[0]
    rel = elements[None, :, :] - pos[:, None, :]  # (S, E, 2) from scatterer to element
    distance = np.hypot(rel[..., 0], rel[..., 1])
    # Diffuse scatterers radiate into their face's half-space with a Lambertian pattern
    # (power ∝ cos θ per leg); edges and clutter are isotropic (zero normal).
    isotropic = ~np.any(normal != 0.0, axis=1)
    cos_out = np.einsum("sed,sd->se", rel, normal) / np.maximum(distance, 1e-12)
    pattern = np.where(isotropic[:, None], 1.0, np.sqrt(np.clip(cos_out, 0.0, None)))
    p0 = np.repeat(pos, num_el, axis=0)
    p1 = np.tile(elements, (count, 1))
    exclude = np.repeat(piece, num_el)
    factor, crossings = _leg_transmission(geom, physics, p0, p1, frequencies_hz, exclude_a=exclude)
    if factor is not None:
        factor = factor.reshape(count, num_el, -1)
    return distance, pattern, factor, crossings.reshape(count, num_el)


def _scatterer_selection(geom, robot_xy, physics):
    if geom.scatter_position_m.shape[0] == 0:
        return np.zeros(0, dtype=int)
    distance = np.hypot(*(geom.scatter_position_m - robot_xy).T)
    keep = distance <= physics["max_range_m"]
    # A diffuse scatterer whose face looks away from the whole robot cannot be lit.
    facing = np.einsum("sd,sd->s", robot_xy - geom.scatter_position_m, geom.scatter_normal)
    isotropic = ~np.any(geom.scatter_normal != 0.0, axis=1)
    keep &= isotropic | (facing > -1.0)  # 1 m of slack covers the arrays' extent
    return np.flatnonzero(keep)


def _cis(length_m, wavenumber):
    """exp(−j k L), (..., N), computed as cos/sin of a real phase (cheaper than complex exp)."""
    phase = np.multiply.outer(length_m, wavenumber)
    out = np.empty(phase.shape, dtype=complex)
    np.cos(phase, out=out.real)
    np.sin(phase, out=out.imag)
    np.negative(out.imag, out=out.imag)
    return out


def _accumulate(channel, paths, wavenumber):
    """channel[k, m, :] += Σ over rows of gain · e^{−jkL}; rows may repeat a (k, m) pair."""
    if paths is None or paths.k.size == 0:
        return
    contribution = paths.gain * _cis(paths.length_m, wavenumber)
    num_rx = channel.shape[1]
    flat = paths.k * num_rx + paths.m
    order = np.argsort(flat, kind="stable")
    flat_sorted = flat[order]
    starts = np.flatnonzero(np.r_[True, flat_sorted[1:] != flat_sorted[:-1]])
    sums = np.add.reduceat(contribution[order], starts, axis=0)
    view = channel.reshape(-1, channel.shape[2])
    view[flat_sorted[starts]] += sums


def _pose_elements(radar, pose):
    """TX and RX element positions in the world frame for pose [x, y, heading]."""
    cos_h, sin_h = math.cos(pose[2]), math.sin(pose[2])
    rotation = np.array([[cos_h, -sin_h], [sin_h, cos_h]])
    offset = np.asarray(pose[:2], dtype=float)
    return radar.tx_elements_m @ rotation.T + offset, radar.rx_elements_m @ rotation.T + offset


def _mimo_channel(scene, geom, tx, rx, frequencies_hz, robot_xy):
    """H[k, m, n] of every path, noiseless, no impairments, no system delay."""
    physics = scene.physics
    frequencies_hz = np.asarray(frequencies_hz, dtype=float)
    wavenumber = 2.0 * np.pi * frequencies_hz / SPEED_OF_LIGHT_M_S
    channel = np.zeros((tx.shape[0], rx.shape[0], frequencies_hz.size), dtype=complex)
    if physics["direct"]:
        _accumulate(channel, _direct_paths(geom, physics, tx, rx, frequencies_hz), wavenumber)
    if physics["reflections"]:
        _accumulate(channel, _first_order_paths(geom, physics, tx, rx, frequencies_hz, robot_xy), wavenumber)
    if physics["second_order"]:
        _accumulate(channel, _second_order_paths(geom, physics, tx, rx, frequencies_hz, robot_xy), wavenumber)
    select = _scatterer_selection(geom, robot_xy, physics)
    if select.size:
        # Point scatterers factorise: Σ_s A[s, k, n]·B[s, m, n], one leg per element each.
        d_t, pat_t, f_t, _ = _scatter_legs(geom, physics, tx, frequencies_hz, select)
        d_r, pat_r, f_r, _ = _scatter_legs(geom, physics, rx, frequencies_hz, select)
        leg_t = _apply(f_t, (pat_t / d_t)[:, :, None] * _cis(d_t, wavenumber))
        leg_r = _apply(f_r, (geom.scatter_amplitude_m[select][:, None] * pat_r / d_r)[:, :, None]
                       * _cis(d_r, wavenumber))
        lam = SPEED_OF_LIGHT_M_S / frequencies_hz
        summed = np.matmul(leg_t.transpose(2, 1, 0), leg_r.transpose(2, 0, 1))  # (N, K, M)
        channel += summed.transpose(1, 2, 0) * (lam / (4.0 * np.pi))
    return channel


def channel_matrix_at_pose(scene, pose, frequencies_hz=None):
    """The MIMO channel H[k, m, n] (K, M, N) complex128 at one pose: every path, for every
    TX element k and RX element m, noiseless, without impairments or system delay."""
    frequencies_hz = scene.radar.frequencies_hz if frequencies_hz is None else np.atleast_1d(frequencies_hz)
    pose = np.asarray(pose, dtype=float)
    tx, rx = _pose_elements(scene.radar, pose)
    return _mimo_channel(scene, building_geometry(scene), tx, rx, frequencies_hz, pose[:2])


def channel_at_pose(scene, pose, tx_weights=None, frequencies_hz=None):
    """The CSI H[m, n] (M, N) complex128 at one pose for TX weights w (K,), default the
    scene's: Σ_k w_k·H[k, m, n]; noiseless, without impairments or system delay."""
    weights = scene_tx_weights(scene) if tx_weights is None else np.asarray(tx_weights, dtype=complex)
    return np.einsum("k,kmn->mn", weights, channel_matrix_at_pose(scene, pose, frequencies_hz))


# ----------------------------------------------------------------------------------------
# TX weights
# ----------------------------------------------------------------------------------------
def steering_vector(elements_m, angle_rad, frequency_hz):
    """Far-field steering vector a(θ)[k] = exp(−j k0 p_k·u(θ)): w = a(θ) beams toward θ."""
    u = np.array([math.cos(angle_rad), math.sin(angle_rad)])
    return np.exp(-2j * np.pi * frequency_hz / SPEED_OF_LIGHT_M_S * (elements_m @ u))


def null_steering_weights(tx_elements_m, rx_elements_m, frequencies_hz, main_lobe_rad, *, carrier_hz=None,
                          wavefront="spherical", null_depth_db=40.0, max_nulls=None):
    """TX weights with the main lobe toward main_lobe_rad and a null on the RX array (eq. 9).

    Eq. 9 removes from a(θd) its projection on the steering vector of the null direction.
    With wavefront="spherical" the null vectors are the exact near-field couplings
    v_{m,f}[k] = e^{+j2πf·d_km/c}/d_km to every RX element m at every design frequency f
    (the field at RX element m is v_{m,f}^H·w); their dominant singular vectors are projected
    out, as many as needed for a worst-case residual null_depth_db below the strongest
    (at most max_nulls, default K − 2). wavefront="plane" is the paper's far-field eq. 9
    toward the RX array's centre, at the carrier. Weights are scaled to max |w_k| = 1.
    """
    tx = np.asarray(tx_elements_m, dtype=float)
    rx = np.asarray(rx_elements_m, dtype=float)
    frequencies_hz = np.atleast_1d(np.asarray(frequencies_hz, dtype=float))
    if carrier_hz is None:
        carrier_hz = float(np.mean(frequencies_hz))
    num_tx = tx.shape[0]
    max_nulls = max(1, num_tx - 2) if max_nulls is None else int(max_nulls)
    desired = steering_vector(tx, main_lobe_rad, carrier_hz)
    if wavefront == "plane":
        towards = rx.mean(axis=0) - tx.mean(axis=0)
        null_vectors = steering_vector(tx, math.atan2(towards[1], towards[0]), carrier_hz)[:, None]
        basis = null_vectors / np.linalg.norm(null_vectors)
    elif wavefront == "spherical":
        distance = np.hypot(*(rx[None, :, :] - tx[:, None, :]).transpose(2, 0, 1))  # (K, M)
        phase = 2.0 * np.pi * np.multiply.outer(distance, frequencies_hz) / SPEED_OF_LIGHT_M_S  # (K, M, F)
        null_vectors = (np.exp(1j * phase) / distance[:, :, None]).reshape(num_tx, -1)
        u, s, _ = np.linalg.svd(null_vectors, full_matrices=False)
        ratio = (s / s[0]) ** 2
        # Smallest rank whose worst leftover direction is null_depth_db down.
        rank = int(np.searchsorted(-ratio, -(10.0 ** (-null_depth_db / 10.0)), side="right"))
        rank = min(max(rank, 1), max_nulls)
        basis = u[:, :rank]
    else:
        raise ValueError(f"wavefront: expected 'spherical' or 'plane', got {wavefront!r}")
    weights = desired - basis @ (basis.conj().T @ desired)
    peak = np.max(np.abs(weights))
    if peak < 1e-12:
        raise ValueError("null steering left no power toward the main lobe; reduce max_nulls or null_depth_db")
    return weights / peak


def scene_tx_weights(scene):
    """The TX weights w (K,) complex128 that the scene's tx_weights section asks for."""
    spec = scene.tx_weights
    radar = scene.radar
    if spec["mode"] == "ones":
        return np.ones(radar.num_tx, dtype=complex)
    if spec["mode"] == "explicit":
        return np.asarray(spec["weights"], dtype=complex)
    frequencies = radar.frequencies_hz if spec["design_band"] == "full" else np.array([radar.carrier_hz])
    return null_steering_weights(radar.tx_elements_m, radar.rx_elements_m, frequencies, spec["main_lobe_rad"],
                                 carrier_hz=radar.carrier_hz, wavefront=spec["wavefront"],
                                 null_depth_db=spec["null_depth_db"], max_nulls=spec["max_nulls"])


# ----------------------------------------------------------------------------------------
# The survey
# ----------------------------------------------------------------------------------------
@dataclass(eq=False)
class SimResult:
    """A simulated survey: what write_survey needs, and the truth behind it."""

    csi: np.ndarray  # (F, M, N) complex64
    frame_types: list  # F strings: "rx_reference" frames first, then "survey" (the TX calibration's first)
    frame_tx_weights: np.ndarray  # (F, K) complex128: the weights each frame records
    poses_odometry: np.ndarray  # (F, 3) what the robot reports; NaN rows for reference frames
    poses_true: np.ndarray  # (F, 3) where it really was; NaN rows for reference frames
    pose_index: np.ndarray  # (F,) index into scene.poses, -1 for reference frames
    tx_weights: np.ndarray  # (K,) complex128
    tx_elements_m: np.ndarray  # (K, 2)
    rx_elements_m: np.ndarray  # (M, 2)
    subcarrier_offsets_hz: np.ndarray  # (N,)
    center_frequency_hz: float
    system_delay_s: float  # the true τ_sys
    system_delay_known: bool  # whether the survey file should state it
    noise_power: float  # per complex sample
    rx_chain_gains: np.ndarray  # (M, N) β_m(f_n)
    tx_chain_gains: np.ndarray  # (K, N) α_k(f_n)
    noiseless_csi: np.ndarray  # (P, M, N) complex128 per pose, with impairments, before noise
    tx_calibration: object  # tx_calibration.TxCalibration the radio applied, or None
    tx_chain_residual: np.ndarray  # (K, N) α_k(f_n)·c_k: the TX chains the survey frames went through
    datetimes: list  # F ISO 8601 strings
    wall_model: dict  # {"relative_permittivity", "thickness_m"} when every wall shares one slab
    elapsed_s: float

    @property
    def frequencies_hz(self):
        return self.center_frequency_hz + self.subcarrier_offsets_hz


def chain_gains(chain, frequencies_hz):
    """Per-chain complex gains 10^(g/20)·e^{jφ}·e^{−j2πfδ}, (count, N)."""
    amplitude = 10.0 ** (chain["gain_db"] / 20.0)
    return (amplitude * np.exp(1j * chain["phase_rad"]))[:, None] * np.exp(
        -2j * np.pi * np.multiply.outer(chain["delay_s"], frequencies_hz))


def odometry_poses(scene, poses_true):
    """What wheel odometry reports for the true poses (P, 3), with the scene's error model.

    Each step's true motion, in the robot frame of the pose it starts from, is scaled by
    (1 + scale_error) and disturbed by position_noise_m per axis; the heading change gains
    heading_drift_deg_per_m per metre travelled plus heading_noise_deg. The report is the
    integral of those steps from the true first pose, so errors accumulate as they do on a
    robot.
    """
    spec = scene.odometry
    rng = _scene.rng_for(scene.seed, _scene.RNG_ODOMETRY)
    count = poses_true.shape[0]
    noise_xy = rng.standard_normal((count, 2)) * spec["position_noise_m"]
    noise_heading = rng.standard_normal(count) * math.radians(spec["heading_noise_deg"])
    reported = np.empty_like(poses_true)
    if count == 0:
        return reported
    reported[0] = poses_true[0]
    for i in range(1, count):
        prev, cur = poses_true[i - 1], poses_true[i]
        c, s = math.cos(prev[2]), math.sin(prev[2])
        delta_world = cur[:2] - prev[:2]
        step_robot = np.array([c * delta_world[0] + s * delta_world[1], -s * delta_world[0] + c * delta_world[1]])
        turn = math.remainder(cur[2] - prev[2], 2.0 * math.pi)
        distance = float(np.hypot(*step_robot))
        if distance == 0.0 and turn == 0.0:
            reported[i] = reported[i - 1]  # standing still: the wheels report nothing
            continue
        step_robot = step_robot * (1.0 + spec["scale_error"]) + noise_xy[i]
        turn = turn + math.radians(spec["heading_drift_deg_per_m"]) * distance + noise_heading[i]
        h = reported[i - 1, 2]
        ch, sh = math.cos(h), math.sin(h)
        reported[i, 0] = reported[i - 1, 0] + ch * step_robot[0] - sh * step_robot[1]
        reported[i, 1] = reported[i - 1, 1] + sh * step_robot[0] + ch * step_robot[1]
        reported[i, 2] = math.remainder(h + turn, 2.0 * math.pi)
    return reported


def scene_wall_model(scene):
    """FORMATS.md's thrumapper:wall_model when every penetrable wall is the same one-layer
    slab (its relative permittivity's real part and thickness), else None."""
    slabs = {(m.layers[0][0], m.layers[0][1]) for m in (w.material for w in scene.walls) if not m.conductor}
    layered = [w for w in scene.walls if not w.material.conductor and not w.material.single_layer]
    if len(slabs) != 1 or layered:
        return None
    eps, thickness_m = slabs.pop()
    return {"relative_permittivity": float(eps.real), "thickness_m": float(thickness_m)}


def _datetimes(scene, count):
    start = scene.timing["start_time"].replace("Z", "+00:00").replace("z", "+00:00")
    try:
        origin = _dt.datetime.fromisoformat(start)
    except ValueError:
        raise _scene.SceneError(f"timing.start_time: not an ISO 8601 time: {scene.timing['start_time']!r}") from None
    if origin.tzinfo is None:
        origin = origin.replace(tzinfo=_dt.timezone.utc)
    origin_ns = int(origin.timestamp()) * 1_000_000_000 + origin.microsecond * 1000
    period_ns = int(round(scene.timing["frame_period_s"] * 1e9))
    stamps = []
    for f in range(count):
        total = origin_ns + f * period_ns
        seconds, nanoseconds = divmod(total, 1_000_000_000)
        text = _dt.datetime.fromtimestamp(seconds, tz=_dt.timezone.utc).strftime("%Y-%m-%dT%H:%M:%S")
        stamps.append(f"{text}.{nanoseconds:09d}Z")
    return stamps


def simulate_survey(scene, progress=True):
    """Simulate the scene's survey: every pose, frames_per_pose frames each, with noise,
    chain impairments, system delay and odometry error; RX reference frames first when the
    scene's RX chains are impaired, then the TX calibration's single-element frames when the
    scene asks for one (impairments.tx_calibration_frames). Returns a SimResult."""
    started = time.perf_counter()
    radar = scene.radar
    frequencies = radar.frequencies_hz
    weights = scene_tx_weights(scene)
    geom = building_geometry(scene)
    impairments = scene.impairments
    beta = chain_gains(impairments["rx"], frequencies)  # (M, N)
    alpha = chain_gains(impairments["tx"], frequencies)  # (K, N)
    system_phase = np.exp(-2j * np.pi * frequencies * impairments["system_delay_s"])
    num_tx, num_rx, num_sc = radar.num_tx, radar.num_rx, radar.num_subcarriers
    cal_frames = impairments["tx_calibration_frames"]
    cal_poses = min(impairments["tx_calibration_poses"], scene.num_poses) if cal_frames else 0

    num_poses = scene.num_poses
    # Per pose and TX element (unit weight, chains applied): the survey frames are their
    # weighted sum, and the TX calibration's frames are single elements of the first poses.
    per_element = np.empty((num_poses, num_tx, num_rx, num_sc), dtype=complex)
    iterator = range(num_poses)
    if progress:
        from tqdm import tqdm

        iterator = tqdm(iterator, desc=f"simulating {scene.name}", unit="pose")
    for p in iterator:
        tx, rx = _pose_elements(radar, scene.poses[p])
        mimo = _mimo_channel(scene, geom, tx, rx, frequencies, scene.poses[p, :2])
        per_element[p] = beta[None] * alpha[:, None, :] * mimo * system_phase
    noiseless = np.einsum("k,pkmn->pmn", weights, per_element)

    if "snr_db" in scene.noise:
        # SNR per sample relative to the survey's mean channel power (before any TX calibration,
        # so that a scene with and without one draws the same noise).
        noise_power = float(np.mean(np.abs(noiseless) ** 2)) / 10.0 ** (scene.noise["snr_db"] / 10.0)
    else:
        noise_power = float(scene.noise["power"])

    offsets = radar.subcarrier_offsets_hz
    spacing = float(np.median(np.diff(offsets))) if offsets.size > 1 else 1.0
    # DC offset lands on the subcarriers next to DC.
    dc_bins = np.abs(offsets) <= 0.5 * spacing * (1.0 + 1e-9)
    num_ref = impairments["rx_reference_frames"]
    reference = impairments["rx_reference_amplitude"] * system_phase  # s(f): one split, equal cables
    fpp = scene.frames_per_pose
    rng = _scene.rng_for(scene.seed, _scene.RNG_NOISE)
    shape = (num_ref + num_poses * fpp, num_rx, num_sc)
    noise = (rng.standard_normal(shape) + 1j * rng.standard_normal(shape)) * math.sqrt(noise_power / 2)
    noise[:, :, dc_bins] += impairments["dc_offset"][None, :, None]
    rx_reference = beta * reference + noise[:num_ref]

    # The radio's TX calibration, before the survey: each element alone (unit weight) at the
    # first poses, through the RX chains as the reference frames calibrate them; the
    # correction it measures multiplies the weights of every survey frame after it, so the
    # survey records the nominal weights (FORMATS.md: α_k = 1 once the radio is calibrated).
    calibration = None
    chain_residual = alpha
    cal_csi = np.empty((0, num_rx, num_sc), dtype=complex)
    cal_pose_index = np.empty(0, dtype=int)
    cal_elements = np.empty(0, dtype=int)
    if cal_frames:
        from . import rx_calibration as _rx_cal
        from . import tx_calibration as _tx_cal

        cal_pose_index = np.repeat(np.arange(cal_poses), num_tx * cal_frames)
        cal_elements = np.tile(np.repeat(np.arange(num_tx), cal_frames), cal_poses)
        # Its own noise stream: the survey's frames draw the same noise with or without it.
        cal_rng = _scene.rng_for(scene.seed, _scene.RNG_TX_CALIBRATION)
        cal_csi = per_element[cal_pose_index, cal_elements]
        cal_csi = cal_csi + (cal_rng.standard_normal(cal_csi.shape) + 1j * cal_rng.standard_normal(cal_csi.shape)) * \
            math.sqrt(noise_power / 2)
        cal_csi[:, :, dc_bins] += impairments["dc_offset"][None, :, None]
        seen = cal_csi
        if num_ref:
            seen = _rx_cal.calibrate_rx(rx_reference, offsets).apply(cal_csi)
        calibration = _tx_cal.calibrate_tx(seen, cal_elements, np.ones(cal_elements.size), radar.tx_elements_m,
                                           radar.rx_elements_m, radar.carrier_hz, offsets, poses=cal_pose_index)
        chain_residual = alpha * calibration.correction[:, None]
        noiseless = np.einsum("k,pkmn->pmn", weights * calibration.correction, per_element)

    num_cal = cal_csi.shape[0]
    num_frames = num_ref + num_cal + num_poses * fpp
    csi = np.concatenate((rx_reference, cal_csi, np.repeat(noiseless, fpp, axis=0) + noise[num_ref:]))

    pose_index = np.concatenate((np.full(num_ref, -1), cal_pose_index, np.repeat(np.arange(num_poses), fpp)))
    poses_true = np.full((num_frames, 3), np.nan)
    poses_odometry = np.full((num_frames, 3), np.nan)
    odometry = odometry_poses(scene, scene.poses)
    poses_true[num_ref:] = scene.poses[pose_index[num_ref:]]
    poses_odometry[num_ref:] = odometry[pose_index[num_ref:]]
    frame_weights = np.tile(weights, (num_frames, 1))
    frame_weights[num_ref:num_ref + num_cal] = np.eye(num_tx, dtype=complex)[cal_elements]
    return SimResult(
        csi=csi.astype(np.complex64),
        frame_types=["rx_reference"] * num_ref + ["survey"] * (num_cal + num_poses * fpp),
        frame_tx_weights=frame_weights,
        poses_odometry=poses_odometry,
        poses_true=poses_true,
        pose_index=pose_index,
        tx_weights=weights,
        tx_elements_m=radar.tx_elements_m.copy(),
        rx_elements_m=radar.rx_elements_m.copy(),
        subcarrier_offsets_hz=offsets.copy(),
        center_frequency_hz=radar.carrier_hz,
        system_delay_s=impairments["system_delay_s"],
        system_delay_known=impairments["system_delay_known"],
        noise_power=noise_power,
        rx_chain_gains=beta,
        tx_chain_gains=alpha,
        noiseless_csi=noiseless,
        tx_calibration=calibration,
        tx_chain_residual=chain_residual,
        datetimes=_datetimes(scene, num_frames),
        wall_model=scene_wall_model(scene),
        elapsed_s=time.perf_counter() - started,
    )


# ----------------------------------------------------------------------------------------
# Geometric truth of the paths at a pose
# ----------------------------------------------------------------------------------------
def _robot_angle_deg(vector_world, heading):
    return math.degrees(math.atan2(vector_world[1], vector_world[0]) - heading) % 360.0


def path_truth(scene, pose, include_diffuse=False, min_amplitude=0.0):
    """Every path at a pose, traced between the array centres: a list of dicts, strongest first.

    Keys: kind ("direct", "wall", "wall_through", "corner", "corner_through", "double",
    "double_through", "clutter", "edge", "diffuse", with "_through" when a leg crosses a wall),
    wall (index into scene.walls, or None), walls (every bounce's wall index), delay_s (the
    geometric delay |path|/c between the array centres, τ_sys excluded: FORMATS.md's τ),
    excess_delay_s (the group delay the wall coefficients add at the carrier, from
    transmission through walls and the slab's own reflection), length_m, aoa_deg (at the RX
    centre, robot frame, [0, 360)), aod_deg (at the TX centre), amplitude and gain (complex,
    at the carrier, per element pair with unit weights), points_m (bounce points, world),
    walls_crossed, name (clutter and edges).
    """
    pose = np.asarray(pose, dtype=float)
    radar = scene.radar
    geom = building_geometry(scene)
    physics = scene.physics
    heading = pose[2]
    cos_h, sin_h = math.cos(heading), math.sin(heading)
    rotation = np.array([[cos_h, -sin_h], [sin_h, cos_h]])
    tx = (rotation @ radar.tx_centre_m + pose[:2])[None, :]
    rx = (rotation @ radar.rx_centre_m + pose[:2])[None, :]
    fc = radar.carrier_hz
    step_hz = 1e6
    frequencies = np.array([fc - step_hz, fc, fc + step_hz])
    paths = []

    def add(kind, length, gain3, bounce_points, bounce_pieces, crossings, name=None):
        gain_fc = gain3[1]
        # Group delay of the coefficients alone: the geometric e^{−jkL} is not in gain3.
        phase_step = np.angle(gain3[2] * np.conj(gain3[0]))
        excess = -phase_step / (2.0 * np.pi * 2.0 * step_hz)
        first = bounce_points[0] if bounce_points else rx[0]
        last = bounce_points[-1] if bounce_points else tx[0]
        walls = [int(geom.wall_index[q]) for q in bounce_pieces]
        if crossings and kind in ("wall", "corner", "double"):
            kind = kind + "_through"
        paths.append({
            "kind": kind,
            "wall": walls[0] if walls else None,
            "walls": walls,
            "delay_s": float(length / SPEED_OF_LIGHT_M_S),
            "excess_delay_s": float(excess) if abs(gain_fc) > 0 else 0.0,
            "length_m": float(length),
            "aoa_deg": _robot_angle_deg(last - rx[0], heading),
            "aod_deg": _robot_angle_deg(first - tx[0], heading),
            "amplitude": float(abs(gain_fc)),
            "gain": complex(gain_fc),
            "points_m": [[float(v) for v in q] for q in bounce_points],
            "walls_crossed": int(crossings),
            "name": name,
        })

    if physics["direct"]:
        d = _direct_paths(geom, physics, tx, rx, frequencies)
        add("direct", d.length_m[0], d.gain[0], [], [], d.crossings[0])
    if physics["reflections"]:
        first = _first_order_paths(geom, physics, tx, rx, frequencies, pose[:2])
        if first is not None:
            for v in range(first.k.size):
                add("wall", first.length_m[v], first.gain[v], [first.points[v, 0]], [first.pieces[v, 0]],
                    first.crossings[v])
    if physics["second_order"]:
        second = _second_order_paths(geom, physics, tx, rx, frequencies, pose[:2])
        if second is not None:
            for v in range(second.k.size):
                a, b = second.pieces[v]
                perpendicular = abs(_cross(geom.direction[a], geom.direction[b])) > 0.5
                add("corner" if perpendicular else "double", second.length_m[v], second.gain[v],
                    [second.points[v, 0], second.points[v, 1]], [a, b], second.crossings[v])
    select = _scatterer_selection(geom, pose[:2], physics)
    if not include_diffuse:
        select = select[geom.scatter_kind[select] != SCATTER_DIFFUSE]
    if select.size:
        d_t, pat_t, f_t, c_t = _scatter_legs(geom, physics, tx, frequencies, select)
        d_r, pat_r, f_r, c_r = _scatter_legs(geom, physics, rx, frequencies, select)
        lam = SPEED_OF_LIGHT_M_S / frequencies
        gain = (lam / (4.0 * np.pi))[None, :] * (geom.scatter_amplitude_m[select] * pat_t[:, 0] * pat_r[:, 0]
                                                 / (d_t[:, 0] * d_r[:, 0]))[:, None]
        gain = _apply(None if f_r is None else f_r[:, 0], _apply(None if f_t is None else f_t[:, 0], gain))
        kinds = {SCATTER_DIFFUSE: "diffuse", SCATTER_EDGE: "edge", SCATTER_CLUTTER: "clutter"}
        for i, s in enumerate(select):
            piece = geom.scatter_piece[s]
            add(kinds[int(geom.scatter_kind[s])], d_t[i, 0] + d_r[i, 0], gain[i],
                [geom.scatter_position_m[s]], [piece] if piece >= 0 else [], c_t[i, 0] + c_r[i, 0],
                name=geom.scatter_name[s] if geom.scatter_name else None)
    paths = [p for p in paths if p["amplitude"] > min_amplitude or p["kind"] == "direct"]
    paths.sort(key=lambda p: -p["amplitude"])
    return paths


# ----------------------------------------------------------------------------------------
# Ground-truth map
# ----------------------------------------------------------------------------------------
def _count_crossings(geom, p0, p1, exclude_a=None, exclude_b=None, chunk=20000):
    """Walls crossed by each segment p0→p1, (L,); in chunks to bound memory."""
    out = np.zeros(p0.shape[0], dtype=int)
    for start in range(0, p0.shape[0], chunk):
        sl = slice(start, start + chunk)
        legs, _, _ = _crossings(geom, p0[sl], p1[sl],
                                None if exclude_a is None else exclude_a[sl],
                                None if exclude_b is None else exclude_b[sl])
        out[sl] = np.bincount(legs, minlength=p0[sl].shape[0])
    return out


def _visibility(geom, points, normals, poses_xy, truth, exclude_a, exclude_b=None, need_both=None):
    """Fewest walls between each point and any pose that sees it, (Q,); -1 where none does.

    normals (Q, 2) or (Q, 2, 2) for corners: a pose sees a point when it is in front of the
    face (of both faces for a concave corner, need_both), within range and incidence.
    """
    num_points = points.shape[0]
    best = np.full(num_points, np.iinfo(int).max)
    cos_limit = math.cos(math.radians(truth["max_incidence_deg"]))
    rel = poses_xy[None, :, :] - points[:, None, :]  # (Q, P, 2)
    distance = np.hypot(rel[..., 0], rel[..., 1])
    ok = (distance <= truth["max_range_m"]) & (distance > 1e-9)
    if normals.ndim == 2:
        cos_in = np.einsum("qpd,qd->qp", rel, normals) / np.maximum(distance, 1e-12)
        ok &= cos_in >= cos_limit
    else:
        cos0 = np.einsum("qpd,qd->qp", rel, normals[:, 0]) / np.maximum(distance, 1e-12)
        cos1 = np.einsum("qpd,qd->qp", rel, normals[:, 1]) / np.maximum(distance, 1e-12)
        both = (cos0 > 0) & (cos1 > 0)
        either = (cos0 > 0) | (cos1 > 0)
        ok &= np.where(need_both[:, None], both, either)
    q, p = np.nonzero(ok)
    if q.size:
        crossings = _count_crossings(geom, points[q], poses_xy[p], exclude_a[q],
                                     None if exclude_b is None else exclude_b[q])
        np.minimum.at(best, q, crossings)
    best[best > truth["max_walls_crossed"]] = -1
    return best


def truth_geojson(scene):
    """The ground-truth map (FORMATS.md GeoJSON, "thrumapper:crs": "local-metres").

    - walls: the faces seen from the true trajectory, cut into the pieces that are seen, each
      a LineString along the face (not the centre line) with class "line_of_sight" (no wall
      between it and some pose) or "hidden" (at most truth.max_walls_crossed walls between);
      a face point counts as seen from a pose within truth.max_range_m, in front of the face,
      at most truth.max_incidence_deg off its normal;
    - corners: where two walls' faces meet, with corner_type concave (a dihedral seen from
      inside) or convex, and the class of the best view;
    - openings: the open doors (a door without a leaf) within truth.max_range_m of a pose, a
      LineString across the gap on the wall's face toward the trajectory;
    - trajectory: the true poses.
    """
    geom = building_geometry(scene)
    truth = scene.truth
    poses_xy = scene.poses[:, :2]
    class_names = {0: "line_of_sight"}
    features = []
    for p in range(geom.num_pieces):
        wall = scene.walls[geom.wall_index[p]]
        for side, sign in ((0, 1.0), (1, -1.0)):
            a0, a1 = geom.face_extent_m[p, side]
            if a1 - a0 < 1e-6:
                continue
            count = max(1, int(math.ceil((a1 - a0) / truth["sample_m"])))
            step = (a1 - a0) / count
            along = a0 + (np.arange(count) + 0.5) * step
            points = geom.face_points(p, side, along).reshape(-1, 2)
            normal = np.tile(sign * geom.normal[p], (count, 1))
            seen = _visibility(geom, points, normal, poses_xy, truth, np.full(count, p))
            # Runs of samples with one class become one LineString.
            edges = np.flatnonzero(np.diff(seen) != 0) + 1
            for run in np.split(np.arange(count), edges):
                level = seen[run[0]]
                if level < 0:
                    continue
                ends = geom.face_points(p, side, np.array([a0 + run[0] * step, a0 + (run[-1] + 1) * step]))
                features.append({
                    "type": "Feature",
                    "geometry": {"type": "LineString", "coordinates": [[float(x), float(y)] for x, y in ends]},
                    "properties": {
                        "kind": "wall",
                        "class": class_names.get(int(level), "hidden"),
                        "confidence": 1.0,
                        "walls_between": int(level),
                        "wall": int(wall.index),
                        "name": wall.name,
                        "door": bool(geom.door[p]),
                        "material": geom.materials[geom.material_index[p]].name,
                        "thickness_m": float(2.0 * geom.half_thickness_m[p]),
                    },
                })
    if geom.corners:
        points = np.array([c["position_m"] for c in geom.corners])
        normals = np.array([np.stack(c["normals"]) for c in geom.corners])
        pieces = np.array([c["pieces"] for c in geom.corners])
        concave = np.array([c["corner_type"] == "concave" for c in geom.corners])
        seen = _visibility(geom, points, normals, poses_xy, truth, pieces[:, 0], pieces[:, 1], need_both=concave)
        for corner, level in zip(geom.corners, seen):
            if level < 0:
                continue
            i, j = corner["pieces"]
            features.append({
                "type": "Feature",
                "geometry": {"type": "Point", "coordinates": [float(v) for v in corner["position_m"]]},
                "properties": {
                    "kind": "corner",
                    "class": class_names.get(int(level), "hidden"),
                    "confidence": 1.0,
                    "corner_type": corner["corner_type"],
                    "walls": [int(geom.wall_index[i]), int(geom.wall_index[j])],
                },
            })
    for i, door in enumerate(scene.doors):
        if door.material is not None:
            continue  # a closed door is wall: its leaf is among the walls above
        # an open doorway: the gap on the wall's face toward the trajectory, where some pose
        # is within truth.max_range_m of it
        wall = scene.walls[door.wall_index]
        direction = (wall.end_m - wall.start_m) / wall.length_m
        normal = np.array([-direction[1], direction[0]])
        centre = wall.start_m + door.position_m * direction
        if not np.any(np.hypot(*(poses_xy - centre).T) <= truth["max_range_m"]):
            continue
        side = 1.0 if float(np.mean(poses_xy - centre, axis=0) @ normal) >= 0 else -1.0
        face = centre + side * 0.5 * wall.thickness_m * normal
        ends = [face + t * direction for t in (-0.5 * door.width_m, 0.5 * door.width_m)]
        features.append({
            "type": "Feature",
            "geometry": {"type": "LineString", "coordinates": [[float(x), float(y)] for x, y in ends]},
            "properties": {"kind": "opening", "confidence": 1.0, "width_m": float(door.width_m), "door": i,
                           "wall": int(wall.index), "name": wall.name},
        })
    features.append({
        "type": "Feature",
        # A LineString needs two positions: a single pose is repeated.
        "geometry": {"type": "LineString",
                     "coordinates": [[float(x), float(y)] for x, y in (poses_xy if scene.num_poses > 1
                                                                       else np.repeat(poses_xy, 2, axis=0))]},
        "properties": {"kind": "trajectory", "headings_rad": [float(h) for h in scene.poses[:, 2]]},
    })
    return {
        "type": "FeatureCollection",
        "thrumapper:crs": "local-metres",
        "thrumapper:scene": scene.name,
        "features": features,
    }
