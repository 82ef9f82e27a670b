#
# SPDX-License-Identifier: GPL-3.0-or-later
#
"""Where a slab wall's echo appears: the apparent angle and delay of a dielectric wall.

A wall of thickness d answers with two echoes, from its front and back faces, about
2·d·√εr/c apart (1.6 ns for 15 cm of plasterboard): closer than the 8 ns resolution of 120 MHz,
so an estimator that fits one path per echo lands between them, and near a thickness
resonance (where the two faces' echoes cancel at some frequencies) even outside them. The map
wants the front face. This module models the echo exactly and measures where a one-path fit
puts it:

- the echo of a wall hypothesis (a face line and its normal, robot frame) is built for every
  TX element k and RX element m by the image method, with the exact path length of each pair
  (spherical wavefronts), at every subcarrier's absolute frequency, with the slab's TE
  reflection coefficient Γ(θ_km, f_n) at each pair's own incidence angle (the characteristic
  matrix of building_sim.slab_coefficients: every internal reflection included) and the
  insertion transmission T of every wall the two legs cross on the way, weighted by the TX
  weights w_k: the same physics as FORMATS.md's channel;
- its apparent (θ, τ) is the maximum of the one-path fit |u(θ, τ)ᴴ h|² / |u|² of the
  far-field manifold u = a(θ) ⊗ g(τ) (JADE's manifold), found on a grid around the geometric
  value and refined on two finer grids: what a high-resolution one-path estimator reports for
  an echo alone;
- the shift (apparent − geometric) is then removed from a measured echo, and the geometry
  solved again (WallFusion iterates this twice, the shift changing slowly with the geometry).

A perfect conductor or a zero-thickness slab has no shift (tested): the model only moves
echoes of walls with two faces.
"""

import math

import numpy as np

from . import bistatic
from . import thrumapper_python as _core
from .building_sim import coefficient_table, interpolate_coefficients, slab_coefficients
from .scene import MATERIAL_PRESETS, Material

C = bistatic.SPEED_OF_LIGHT_M_S


def material_from(spec):
    """A scene.Material from a preset name, a FORMATS.md wall_model dict
    {"relative_permittivity": εr, "thickness_m": d}, a Material, or None (None)."""
    if spec is None or isinstance(spec, Material):
        return spec
    if isinstance(spec, str):
        if spec not in MATERIAL_PRESETS:
            raise ValueError(f"material: unknown preset {spec!r}; known: {', '.join(sorted(MATERIAL_PRESETS))}")
        return MATERIAL_PRESETS[spec]
    if isinstance(spec, dict):
        try:
            eps = complex(spec["relative_permittivity"])
            thickness_m = float(spec["thickness_m"])
        except (KeyError, TypeError, ValueError):
            raise ValueError("wall_model: expected {\"relative_permittivity\": number, \"thickness_m\": number}, "
                             f"got {spec!r}") from None
        if not (math.isfinite(eps.real) and eps.real >= 1.0 and math.isfinite(thickness_m) and thickness_m > 0):
            raise ValueError(f"wall_model: relative_permittivity must be >= 1 and thickness_m > 0, got {spec!r}")
        if eps.imag == 0.0:
            eps = complex(eps.real, -eps.real * loss_tangent_for(eps.real))
        return Material("wall_model", ((eps, thickness_m),))
    raise ValueError(f"material: expected a preset name or a wall model dict, got {spec!r}")


#: Loss tangent assumed for a wall model that gives only the real permittivity (FORMATS.md's
#: thrumapper:wall_model): a lossless slab has exact zeros of Γ at its thickness resonances,
#: which no real wall has, and near them the apparent delay of its echo is undefined.
DEFAULT_LOSS_TANGENT = 0.05


def loss_tangent_for(eps_real):
    """The loss tangent of the dielectric preset whose permittivity is nearest eps_real (within
    15 %), else DEFAULT_LOSS_TANGENT."""
    best, best_gap = None, None
    for material in MATERIAL_PRESETS.values():
        if material.conductor or not material.single_layer:
            continue
        eps = material.layers[0][0]
        gap = abs(eps.real - eps_real) / eps_real
        if gap <= 0.15 and (best_gap is None or gap < best_gap):
            best, best_gap = -eps.imag / eps.real, gap
    return DEFAULT_LOSS_TANGENT if best is None else best


def transmission_delay_s(material, incidence_rad, frequency_hz):
    """Extra group delay of one crossing of the wall (insertion coefficient), at a frequency."""
    if material is None or material.conductor:
        return 0.0
    step_hz = 1e6
    f = np.array([frequency_hz - step_hz, frequency_hz + step_hz])
    _, t = slab_coefficients(material, math.cos(incidence_rad), f)
    t = np.ravel(t)
    return float(-np.angle(t[1] * np.conj(t[0])) / (2.0 * np.pi * 2.0 * step_hz))


class EchoModel:
    """The radar's view of a wall's echo (see the module's description).

    tx_elements_m, rx_elements_m: (K, 2), (M, 2) robot frame; tx_weights (K,) complex;
    carrier_hz; subcarrier_offsets_hz (N,).
    """

    def __init__(self, tx_elements_m, rx_elements_m, tx_weights, carrier_hz, subcarrier_offsets_hz):
        self.tx_m = np.asarray(tx_elements_m, float).reshape(-1, 2)
        self.rx_m = np.asarray(rx_elements_m, float).reshape(-1, 2)
        self.weights = np.asarray(tx_weights, complex).reshape(-1)
        if self.weights.size != self.tx_m.shape[0]:
            raise ValueError(f"tx_weights: {self.weights.size} weights for {self.tx_m.shape[0]} TX elements")
        self.carrier_hz = float(carrier_hz)
        self.offsets_hz = np.asarray(subcarrier_offsets_hz, float)
        self.freqs_hz = self.carrier_hz + self.offsets_hz
        self.tx_centre_m = self.tx_m.mean(axis=0)
        self.rx_centre_m = self.rx_m.mean(axis=0)
        self._rx_rel = self.rx_m - self.rx_centre_m
        self._cache = {}
        self._tables = {}
        self._k_hz = 2.0 * np.pi * self.freqs_hz / C  # wavenumbers, rad/m
        self._lambda_m = C / self.freqs_hz
        # echo_csi's C++ core (slab_echo) and the ids of the tables registered with it, per
        # material: {id(material): (material, Γ table id, T table id)}
        self._echo_core = _core.slab_echo(self.tx_m, self.rx_m, self.carrier_hz, [float(f) for f in self.offsets_hz])
        self._core_tables = {}
        self._no_crossed = np.zeros((0, 2))
        self._no_basis = np.zeros((0, 0), complex)

    def coefficients(self, material, cos_incidence, which=0):
        """Γ (which=0) or the insertion T (which=1) of a material at these incidence cosines
        (any shape) and the model's subcarriers: shape (..., N). Interpolated in the
        simulator's table (building_sim.coefficient_table), made once per material here: the
        slab formula itself costs ~1 ms per 8x8 element pairs."""
        return interpolate_coefficients(self._table(material)[which], cos_incidence)

    def _table(self, material):
        """building_sim.coefficient_table of a material at the model's subcarriers, made once."""
        cached = self._tables.get(id(material))
        if cached is None or cached[0] is not material:
            cached = (material, coefficient_table(material, self.freqs_hz))
            self._tables[id(material)] = cached
        return cached[1]

    def _core_table_ids(self, material):
        """(Γ, T) table ids of a material in the C++ core, registered on first use; -1, -1 for
        None (echo_csi's perfect conductor: Γ = -1)."""
        if material is None:
            return -1, -1
        cached = self._core_tables.get(id(material))
        if cached is None or cached[0] is not material:
            table = self._table(material)  # (a conductor's: Γ = -1, T = 0)
            cached = (material, self._echo_core.add_table(table[0]), self._echo_core.add_table(table[1]))
            self._core_tables[id(material)] = cached
        return cached[1], cached[2]

    # -- the echo ------------------------------------------------------------------------
    def echo_csi(self, face_point_m, normal, material, crossed=()):
        """(M, N) CSI of the specular echo of one wall, system delay 0, robot frame.

        crossed: walls in front of it, ((face_point, normal, material), ...): each leg that
        crosses one is multiplied by that wall's insertion transmission at the leg's angle.

        Computed by the C++ core (thrumapper.slab_echo); echo_csi_reference is the same in
        numpy (benchmarks/bench_echo_model.py compares them).
        """
        gamma_id = self._core_table_ids(material)[0]
        if crossed:
            # a crossed wall of no material has table -1, which the core ignores: no loss
            points = np.array([c[0] for c in crossed], float).reshape(-1, 2)
            normals = np.array([c[1] for c in crossed], float).reshape(-1, 2)
            ids = [self._core_table_ids(c[2])[1] for c in crossed]
            return self._echo_core.echo(face_point_m, normal, gamma_id, self.weights, points, normals, ids)
        return self._echo_core.echo(face_point_m, normal, gamma_id, self.weights, self._no_crossed,
                                    self._no_crossed, [])

    def trial_energies(self, pose, tx_centre_m, rx_centre_m, wall, pivot_m, trials, material, crossings,
                       blocker_material, system_response, basis, rows):
        """The CSI fit's objective (J, (T,)) for trial placements (offset_m, rotation_rad) of
        wall dict `wall` (world centre, normal, t0, t1 with its visibility margin already
        added) turned about pivot_m, at world pose (x, y, heading): each trial's echo of
        `material`, its legs through `crossings` (wall_refinement._Crossings) of
        `blocker_material`, times system_response, projected away from basis ((M*N, B) or
        None), scored against rows (F, M*N); 0 where the pose does not see it. The C++ core
        does it all (slab_echo.trial_energies): the fits ask for it ~10^4 times a map."""
        return np.asarray(self._echo_core.trial_energies(
            pose, tx_centre_m, rx_centre_m, wall["centre"], wall["normal"], float(wall["t0"]), float(wall["t1"]),
            pivot_m, np.asarray(trials, float).reshape(-1, 2), self._core_table_ids(material)[0], self.weights,
            crossings.ends_m, crossings.points_m, crossings.normals, self._core_table_ids(blocker_material)[1],
            system_response, self._no_basis if basis is None else basis, rows))

    def echo_csi_reference(self, face_point_m, normal, material, crossed=()):
        """echo_csi in numpy: the plain reference of the benchmark (and the model's first
        form)."""
        n = np.asarray(normal, float) / np.hypot(*normal)
        q = np.asarray(face_point_m, float)
        image = bistatic.mirror(self.tx_m, q, n)  # (K, 2)
        v = self.rx_m[None, :, :] - image[:, None, :]  # (K, M, 2)
        length_m = np.linalg.norm(v, axis=2)
        cos_inc = np.abs(v @ n) / length_m
        if material is None:
            gamma = -np.ones((1, 1, self.freqs_hz.size), complex)
        else:
            gamma = self.coefficients(material, cos_inc, 0)
        # λ/(4πL)·e^{−j2πfL/c}: the 1/L per pair and λ per subcarrier are applied apart
        phase = np.multiply.outer(length_m, self._k_hz)  # (K, M, N) radians
        gain = gamma * (np.cos(phase) - 1j * np.sin(phase))
        gain *= (1.0 / (4.0 * np.pi * length_m))[..., None]
        if crossed:
            t_hit = ((q - image) @ n)[:, None] / (v @ n)
            bounce = image[:, None, :] + t_hit[..., None] * v  # (K, M, 2)
            legs = ((np.broadcast_to(self.tx_m[:, None, :], bounce.shape), bounce),
                    (bounce, np.broadcast_to(self.rx_m[None, :, :], bounce.shape)))
            for q2, n2, material2 in crossed:
                if material2 is None:
                    continue
                n2 = np.asarray(n2, float) / np.hypot(*n2)
                q2 = np.asarray(q2, float)
                for a, b in legs:
                    side_a = (a - q2) @ n2
                    side_b = (b - q2) @ n2
                    hit = side_a * side_b < 0.0
                    if not np.any(hit):
                        continue
                    leg = b - a
                    cos_leg = np.abs(leg @ n2) / np.linalg.norm(leg, axis=2)
                    t = self.coefficients(material2, cos_leg, 1)
                    gain = gain * np.where(hit[..., None], t, 1.0)
        return np.einsum("k,kmn->mn", self.weights, gain) * self._lambda_m

    def _double_images(self, q1, n1, q2, n2):
        """TX → face 1 (through q1, unit normal n1) → face 2 → RX for every element pair, by
        imaging the TX element in face 1 and then in face 2: (path length (K, M), last leg
        (K, M, 2), middle leg (K, M, 2), first bounce point, second bounce point, and where
        each bounce lies along its leg, t1 and t2, in (0, 1) for a real path)."""
        image1 = bistatic.mirror(self.tx_m, q1, n1)  # (K, 2)
        image12 = bistatic.mirror(image1, q2, n2)
        v = self.rx_m[None, :, :] - image12[:, None, :]  # (K, M, 2): the last leg's line
        length_m = np.linalg.norm(v, axis=2)
        with np.errstate(divide="ignore", invalid="ignore"):
            t2 = ((q2 - image12) @ n2)[:, None] / (v @ n2)
            second = image12[:, None, :] + t2[..., None] * v
            w = second - image1[:, None, :]
            t1 = ((q1 - image1) @ n1)[:, None] / (w @ n1)
            first = image1[:, None, :] + t1[..., None] * w
        return length_m, v, w, first, second, t1, t2

    def _double_gain(self, ok, length_m, v, w, n1, n2, material):
        """(M, N) CSI of the double bounces of the pairs `ok` (from _double_images): Γ at both
        bounces' incidences, λ/(4πL), the TX weights; system delay 0."""
        cos2 = np.where(ok, np.abs(v @ n2) / length_m, 1.0)
        cos1 = np.where(ok, np.abs(w @ n1) / np.linalg.norm(w, axis=2), 1.0)
        if material is None:
            gamma = np.ones((1, 1, self.freqs_hz.size), complex)  # two conductor bounces: (−1)²
        else:
            gamma = self.coefficients(material, cos1, 0) * self.coefficients(material, cos2, 0)
        phase = np.multiply.outer(length_m, self._k_hz)
        gain = gamma * (np.cos(phase) - 1j * np.sin(phase))
        gain *= (ok / (4.0 * np.pi * length_m))[..., None]
        return np.einsum("k,kmn->mn", self.weights, gain) * self._lambda_m

    def double_csi(self, first_point_m, first_normal, second_point_m, second_normal, material):
        """(M, N) CSI of the double bounce TX → wall 1 → wall 2 → RX between two infinite
        faces (a corridor's walls facing each other), system delay 0, robot frame: each
        element pair's own path length and incidences, Γ of `material` at both bounces. A
        pair whose bounces fall behind a focus or on a face's back adds nothing. The C++
        core's (slab_echo.double_echo); double_csi_reference is the same in numpy."""
        return self._echo_core.double_echo(first_point_m, first_normal, second_point_m, second_normal,
                                           self._core_table_ids(material)[0], self.weights)

    def double_csi_reference(self, first_point_m, first_normal, second_point_m, second_normal, material):
        """double_csi in numpy (its first form)."""
        q1 = np.asarray(first_point_m, float)
        q2 = np.asarray(second_point_m, float)
        n1 = np.asarray(first_normal, float) / np.hypot(*first_normal)
        n2 = np.asarray(second_normal, float) / np.hypot(*second_normal)
        length_m, v, w, first, second, t1, t2 = self._double_images(q1, n1, q2, n2)
        with np.errstate(invalid="ignore"):
            ok = ((t2 > 0) & (t2 < 1) & (t1 > 0) & (t1 < 1) & ((second - q1) @ n1 > 0) & ((first - q2) @ n2 > 0)
                  & ((self.tx_m - q1) @ n1 > 0)[:, None] & ((self.rx_m - q2) @ n2 > 0)[None, :])
        if not np.any(ok):
            return np.zeros((self.rx_m.shape[0], self.freqs_hz.size), complex)
        return self._double_gain(ok, length_m, v, w, n1, n2, material)

    def corner_csi(self, corner_m, normal_a, normal_b, material):
        """(M, N) CSI of a concave corner's double bounce (TX → face a → face b → RX and TX →
        b → a → RX), system delay 0, robot frame. The faces are half-lines from corner_m, each
        running into the side the other faces (a room's inside corner); normals point into
        the room. A pair (k, m) whose bounce points fall off either face adds nothing. For
        perpendicular faces the path is the one via the point image of TX through the
        corner: the echo seems to come from the corner itself (a retro-reflector). The C++
        core's (slab_echo.corner_echo); corner_csi_reference is the same in numpy."""
        return self._echo_core.corner_echo(corner_m, normal_a, normal_b, self._core_table_ids(material)[0],
                                           self.weights)

    def corner_csi_reference(self, corner_m, normal_a, normal_b, material):
        """corner_csi in numpy (its first form)."""
        c = np.asarray(corner_m, float)
        n_a = np.asarray(normal_a, float) / np.hypot(*normal_a)
        n_b = np.asarray(normal_b, float) / np.hypot(*normal_b)
        d_a = np.array([-n_a[1], n_a[0]])
        d_a = d_a if d_a @ n_b > 0 else -d_a
        d_b = np.array([-n_b[1], n_b[0]])
        d_b = d_b if d_b @ n_a > 0 else -d_b
        total = np.zeros((self.rx_m.shape[0], self.freqs_hz.size), complex)
        # both arrays in front of both faces (inside the room)
        in_front = (np.all((self.tx_m - c) @ np.column_stack((n_a, n_b)) > 0, axis=1)[:, None] &
                    np.all((self.rx_m - c) @ np.column_stack((n_a, n_b)) > 0, axis=1)[None, :])
        for (n1, d1), (n2, d2) in (((n_a, d_a), (n_b, d_b)), ((n_b, d_b), (n_a, d_a))):
            length_m, v, w, first, second, t1, t2 = self._double_images(c, n1, c, n2)
            with np.errstate(invalid="ignore"):
                ok = ((second - c) @ d2 >= 0) & ((first - c) @ d1 >= 0) & (t2 > 0) & (t2 < 1) & (t1 > 0) & (t1 < 1) & in_front
            if np.any(ok):
                total += self._double_gain(ok, length_m, v, w, n1, n2, material)
        return total

    # -- a one-path fit ------------------------------------------------------------------
    def _fit_surface(self, h, angles_rad, delays_s):
        a = np.exp(2j * np.pi * self.carrier_hz / C * (self._rx_rel @ bistatic.bearing_vector(angles_rad).T))  # (M, A)
        g = np.exp(-2j * np.pi * np.outer(self.offsets_hz, delays_s))  # (N, D)
        return np.abs(a.conj().T @ h @ g.conj()) ** 2  # (A, D)

    def apparent(self, h, aoa_rad, delay_s):
        """(θ, τ) of the best one-path fit of CSI h near (aoa_rad, delay_s)."""
        theta, tau = float(aoa_rad), float(delay_s)
        for half_deg, step_deg, half_ns, step_ns in ((10.0, 0.5, 3.0, 0.1), (0.6, 0.05, 0.12, 0.01),
                                                     (0.06, 0.005, 0.012, 0.001)):
            angles = theta + np.radians(np.arange(-half_deg, half_deg + 1e-9, step_deg))
            delays = tau + 1e-9 * np.arange(-half_ns, half_ns + 1e-12, step_ns)
            surface = self._fit_surface(h, angles, delays)
            i, j = np.unravel_index(int(np.argmax(surface)), surface.shape)
            theta, tau = float(angles[i]), float(delays[j])
        # a parabola through the last grid's neighbours
        if 0 < i < surface.shape[0] - 1:
            y0, y1, y2 = surface[i - 1, j], surface[i, j], surface[i + 1, j]
            den = y0 - 2 * y1 + y2
            if den < 0:
                theta += 0.5 * (y0 - y2) / den * (angles[1] - angles[0])
        if 0 < j < surface.shape[1] - 1:
            y0, y1, y2 = surface[i, j - 1], surface[i, j], surface[i, j + 1]
            den = y0 - 2 * y1 + y2
            if den < 0:
                tau += 0.5 * (y0 - y2) / den * (delays[1] - delays[0])
        return theta % (2.0 * math.pi), tau

    def shift(self, face_point_m, normal, material, crossed=()):
        """(Δθ rad, Δτ s): where the wall's echo appears minus its geometric specular path
        between the array centres. (0, 0) when the wall has no specular path."""
        if material is None or (not material.conductor and material.thickness_m <= 0):
            if not crossed:
                return 0.0, 0.0
        try:
            theta_g, tau_g, _ = bistatic.specular_path(face_point_m, normal, self.tx_centre_m, self.rx_centre_m)
        except bistatic.GeometryError:
            return 0.0, 0.0
        h = self.echo_csi(face_point_m, normal, material, crossed)
        theta_a, tau_a = self.apparent(h, theta_g, tau_g)
        d_theta = (theta_a - theta_g + math.pi) % (2.0 * math.pi) - math.pi
        d_tau = tau_a - tau_g
        # An echo train spans the front face to the last internal bounce that matters; a
        # one-path fit outside [-span, +span] is the fit failing (a resonance), not the wall.
        span_s = self.echo_span_s(material) + sum(self.echo_span_s(c[2]) for c in crossed)
        if abs(d_tau) > span_s:
            return 0.0, 0.0
        return d_theta, d_tau

    @staticmethod
    def echo_span_s(material):
        """Twice the slab's optical thickness: the delay from its front-face echo to its
        back-face echo at normal incidence (0 for a conductor)."""
        if material is None or material.conductor:
            return 0.0
        return float(sum(2.0 * d * math.sqrt(abs(eps.real)) / C for eps, d in material.layers))

    def cached_shift(self, face_point_m, normal, material, crossed=(), resolution_m=0.01, resolution_rad=math.radians(0.5)):
        """shift() on a wall quantised to resolution_m in stand-off and resolution_rad in
        orientation (and likewise the crossed walls), memoised: a survey along one wall asks
        for the same geometry at every pose."""
        def key_of(point, nrm, mat):
            nrm = np.asarray(nrm, float) / np.hypot(*nrm)
            phi = math.atan2(nrm[1], nrm[0])
            rho = float(np.dot(np.asarray(point, float), nrm))
            return (round(phi / resolution_rad), round(rho / resolution_m), id(mat))

        key = (key_of(face_point_m, normal, material),) + tuple(key_of(*c) for c in crossed)
        value = self._cache.get(key)
        if value is None:
            def snapped(k, mat):
                phi = k[0] * resolution_rad
                nrm = np.array([math.cos(phi), math.sin(phi)])
                return nrm * (k[1] * resolution_m), nrm, mat

            point, nrm, mat = snapped(key[0], material)
            crossed_snapped = tuple(snapped(k, c[2]) for k, c in zip(key[1:], crossed))
            value = self.shift(point, nrm, mat, crossed_snapped)
            if len(self._cache) > 200000:
                self._cache.clear()
            self._cache[key] = value
        return value
