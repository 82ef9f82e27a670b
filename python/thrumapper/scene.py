#
# SPDX-License-Identifier: GPL-3.0-or-later
#
"""Scenes for the simulated building: the YAML schema, its validation and the material presets.

A scene is a floor plan (walls with doors, clutter), a trajectory, the radar and what can go
wrong with it (noise, chain impairments, odometry error). `load_scene` reads a YAML file (or a
dict of the same shape), checks every field and returns a `Scene` whose numbers are numpy
arrays in SI units. Every error is a `SceneError` whose message starts with the field's path,
for instance ``walls[2].material: unknown material 'plaster'``.

docs/simulator.md describes the schema with its units; the conventions are those of
FORMATS.md (world frame, robot frame +x forward +y left, pose [x, y, heading], radians inside).

Geometry convention: a wall's `segment` is its **centre line**. Its material (a slab of
`thickness_m`) extends by thickness/2 on each side, so both of its faces are known without
choosing a side, and the ground truth reports whichever face the robot looks at.
"""

import math
import os
from dataclasses import dataclass, field

import numpy as np

SPEED_OF_LIGHT_M_S = 299792458.0


class SceneError(ValueError):
    """A scene that breaks the schema; the message starts with the offending field."""


# ----------------------------------------------------------------------------------------
# Materials
# ----------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Material:
    """A wall material: a stack of dielectric layers, or a perfect conductor.

    layers: ((relative_permittivity complex, thickness_m), ...), front to back. The sign
    convention is engineering e^{+jωt}: a lossy εr has a negative imaginary part.
    """

    name: str
    layers: tuple
    conductor: bool = False
    conductor_thickness_m: float = 0.0

    @property
    def thickness_m(self):
        if self.conductor:
            return self.conductor_thickness_m
        return float(sum(d for _, d in self.layers))

    @property
    def single_layer(self):
        return (not self.conductor) and len(self.layers) == 1

    def with_thickness(self, thickness_m):
        """The same material with another total thickness (one-layer slabs and conductors)."""
        if self.conductor:
            return Material(self.name, (), True, float(thickness_m))
        if not self.single_layer:
            raise ValueError(f"material '{self.name}' has {len(self.layers)} layers; its thickness is fixed")
        return Material(self.name, ((self.layers[0][0], float(thickness_m)),))


# Complex permittivities at 2.44 GHz from ITU-R P.2040-3, Table 3: εr' = a·f^b and
# σ = c·f^d (f in GHz), εr'' = σ / (2π f ε0). Thicknesses are typical builds.
_GYPSUM_EPS = complex(2.73, -0.145)  # plasterboard: a=2.73, c=0.0085, d=0.9395
MATERIAL_PRESETS = {
    # The paper's walls: 15 cm of plasterboard, modelled as one solid slab (εr ≈ 2.7), the
    # wall model FORMATS.md's thrumapper:wall_model describes.
    "plasterboard": Material("plasterboard", ((_GYPSUM_EPS, 0.15),)),
    # A stud partition as built: two 12.5 mm gypsum boards on a 125 mm air cavity.
    "stud_wall": Material("stud_wall", ((_GYPSUM_EPS, 0.0125), (1.0 + 0j, 0.125), (_GYPSUM_EPS, 0.0125))),
    "brick": Material("brick", ((complex(3.91, -0.202), 0.20),)),  # a=3.91, c=0.0238, d=0.16
    "concrete": Material("concrete", ((complex(5.24, -0.684), 0.20),)),  # a=5.24, c=0.0462, d=0.7822
    "glass": Material("glass", ((complex(6.31, -0.0876), 0.012),)),  # a=6.31, c=0.0036, d=1.3394
    "wood": Material("wood", ((complex(1.99, -0.090), 0.04),)),  # a=1.99, c=0.0047, d=1.0718
    # Sheet metal: Γ = -1, nothing gets through.
    "metal": Material("metal", (), conductor=True, conductor_thickness_m=0.002),
}

# Point-scatterer presets: radar cross-section at 2.4 GHz, m² (order of magnitude values).
CLUTTER_PRESETS = {
    "desk": 0.3,
    "chair": 0.05,
    "computer": 0.2,
    "person": 0.5,
    "metal_cabinet": 3.0,
    "radiator": 1.0,
}


# ----------------------------------------------------------------------------------------
# The scene
# ----------------------------------------------------------------------------------------
@dataclass(eq=False)
class Wall:
    index: int
    name: str
    start_m: np.ndarray  # (2,) centre-line start, world frame
    end_m: np.ndarray  # (2,) centre-line end
    material: Material

    @property
    def thickness_m(self):
        return self.material.thickness_m

    @property
    def length_m(self):
        return float(np.hypot(*(self.end_m - self.start_m)))


@dataclass(eq=False)
class Door:
    wall_index: int
    position_m: float  # door centre, metres along the wall from its segment's first point
    width_m: float
    material: Material = None  # None: an open gap; else a closed door leaf of this material


@dataclass(eq=False)
class Radar:
    carrier_hz: float
    subcarrier_offsets_hz: np.ndarray  # (N,) ascending
    tx_elements_m: np.ndarray  # (K, 2) robot frame
    rx_elements_m: np.ndarray  # (M, 2) robot frame

    @property
    def frequencies_hz(self):
        """Absolute subcarrier frequencies fc + Δf_n, (N,)."""
        return self.carrier_hz + self.subcarrier_offsets_hz

    @property
    def tx_centre_m(self):
        return self.tx_elements_m.mean(axis=0)

    @property
    def rx_centre_m(self):
        return self.rx_elements_m.mean(axis=0)

    @property
    def num_tx(self):
        return self.tx_elements_m.shape[0]

    @property
    def num_rx(self):
        return self.rx_elements_m.shape[0]

    @property
    def num_subcarriers(self):
        return self.subcarrier_offsets_hz.size


@dataclass(eq=False)
class Scene:
    """A validated scene. Arrays are numpy, SI units, world frame unless the name says robot."""

    name: str
    description: str
    seed: int
    radar: Radar
    walls: list
    doors: list
    clutter_names: list
    clutter_position_m: np.ndarray  # (C, 2)
    clutter_amplitude_m: np.ndarray  # (C,) complex scattering amplitude √(σ/4π)·e^{jφ}, metres
    poses: np.ndarray  # (P, 3) true poses [x, y, heading]
    frames_per_pose: int
    tx_weights: dict  # {"mode": "ones"} | {"mode": "explicit", "weights": (K,)} | null_steer spec
    noise: dict  # {"power": float} | {"snr_db": float} | {"power": 0.0}
    impairments: dict
    odometry: dict
    physics: dict
    truth: dict
    timing: dict
    source_path: str = None
    materials: dict = field(default_factory=dict)

    @property
    def num_poses(self):
        return self.poses.shape[0]

    @property
    def num_frames(self):
        return self.num_poses * self.frames_per_pose


# ----------------------------------------------------------------------------------------
# Field readers: each names the field's path in its errors
# ----------------------------------------------------------------------------------------
def _fail(where, message):
    raise SceneError(f"{where}: {message}")


def _mapping(value, where, known):
    if not isinstance(value, dict):
        _fail(where, f"expected a mapping, got {_short(value)}")
    unknown = sorted(set(value) - set(known), key=str)
    if unknown:
        _fail(f"{where}.{unknown[0]}" if where else str(unknown[0]),
              f"unknown field (known here: {', '.join(sorted(known))})")
    return value


def _short(value, limit=60):
    text = repr(value)
    return text if len(text) <= limit else text[: limit - 3] + "..."


def _number(value, where, *, lo=None, hi=None, lo_open=False, integer=False):
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        # YAML 1.1 reads "1e-9" (no dot) as a string; accept numeric strings.
        if isinstance(value, str):
            try:
                value = float(value)
            except ValueError:
                _fail(where, f"expected a number, got {_short(value)}")
        else:
            _fail(where, f"expected a number, got {_short(value)}")
    if not math.isfinite(value):
        _fail(where, f"expected a finite number, got {value}")
    if integer:
        if float(value) != int(value):
            _fail(where, f"expected an integer, got {value}")
        value = int(value)
    if lo is not None and (value < lo or (lo_open and value == lo)):
        _fail(where, f"must be {'>' if lo_open else '>='} {lo}, got {value}")
    if hi is not None and value > hi:
        _fail(where, f"must be <= {hi}, got {value}")
    return value


def _complex(value, where):
    """εr as a number, [re, im] or a Python complex literal such as "2.7-0.1j"."""
    if isinstance(value, str):
        try:
            result = complex(value.replace(" ", ""))
        except ValueError:
            _fail(where, f"expected a complex number like 2.7-0.1j or [2.7, -0.1], got {_short(value)}")
    elif isinstance(value, (list, tuple)):
        if len(value) != 2:
            _fail(where, f"expected [re, im], got {_short(value)}")
        result = complex(_number(value[0], f"{where}[0]"), _number(value[1], f"{where}[1]"))
    else:
        result = complex(_number(value, where))
    if not (math.isfinite(result.real) and math.isfinite(result.imag)):
        _fail(where, "must be finite")
    return result


def _point(value, where):
    if not isinstance(value, (list, tuple)) or len(value) != 2:
        _fail(where, f"expected a point [x, y] in metres, got {_short(value)}")
    return np.array([_number(value[0], f"{where}[0]"), _number(value[1], f"{where}[1]")], dtype=float)


def _points(value, where, *, min_count=1):
    if not isinstance(value, (list, tuple)) or len(value) < min_count:
        _fail(where, f"expected a list of at least {min_count} points [x, y], got {_short(value)}")
    return np.array([_point(p, f"{where}[{i}]") for i, p in enumerate(value)], dtype=float).reshape(-1, 2)


def _bool(value, where):
    if not isinstance(value, bool):
        _fail(where, f"expected true or false, got {_short(value)}")
    return value


def _string(value, where):
    if not isinstance(value, str) or not value:
        _fail(where, f"expected a non-empty string, got {_short(value)}")
    return value


def _get(section, key, default, reader, where, **kwargs):
    if key not in section or section[key] is None:
        return default
    return reader(section[key], f"{where}.{key}" if where else key, **kwargs)


# ----------------------------------------------------------------------------------------
# Sections
# ----------------------------------------------------------------------------------------
def uca_positions(count, radius_m, rotation_rad=0.0, centre_x_m=0.0, centre_y_m=0.0):
    """A uniform circular array: element i at angle rotation + 2πi/count (radar_description)."""
    angles = rotation_rad + 2.0 * np.pi * np.arange(count) / count
    return np.column_stack((centre_x_m + radius_m * np.cos(angles), centre_y_m + radius_m * np.sin(angles)))


def uniform_subcarriers(count, bandwidth_hz):
    """N offsets (n - (N-1)/2)·B/N, ascending, centred on zero (radar_description)."""
    return (np.arange(count) - (count - 1) / 2.0) * (bandwidth_hz / count)


_RADAR_KEYS = {"elements", "radius_m", "baseline_m", "carrier_hz", "bandwidth_hz", "subcarriers",
               "rotation_rad", "rotation_deg", "tx_elements", "rx_elements", "subcarrier_offsets_hz"}


def _read_radar(section):
    where = "radar"
    section = _mapping(section or {}, where, _RADAR_KEYS)
    elements = _get(section, "elements", 8, _number, where, lo=1, integer=True)
    radius_m = _get(section, "radius_m", 0.08, _number, where, lo=0.0)
    baseline_m = _get(section, "baseline_m", 0.7, _number, where, lo=0.0)
    carrier_hz = _get(section, "carrier_hz", 2.44e9, _number, where, lo=0.0, lo_open=True)
    bandwidth_hz = _get(section, "bandwidth_hz", 120e6, _number, where, lo=0.0, lo_open=True)
    subcarriers = _get(section, "subcarriers", 128, _number, where, lo=1, integer=True)
    if "rotation_rad" in section and "rotation_deg" in section:
        _fail(f"{where}.rotation_deg", "give rotation_rad or rotation_deg, not both")
    rotation_rad = _get(section, "rotation_rad", None, _number, where)
    if rotation_rad is None:
        rotation_rad = math.radians(_get(section, "rotation_deg", 0.0, _number, where))

    if "tx_elements" in section:
        tx_m = _points(section["tx_elements"], f"{where}.tx_elements")
    else:
        tx_m = uca_positions(elements, radius_m, rotation_rad, -baseline_m / 2.0, 0.0)
    if "rx_elements" in section:
        rx_m = _points(section["rx_elements"], f"{where}.rx_elements")
    else:
        rx_m = uca_positions(elements, radius_m, rotation_rad, baseline_m / 2.0, 0.0)
    if "subcarrier_offsets_hz" in section:
        value = section["subcarrier_offsets_hz"]
        if not isinstance(value, (list, tuple)) or not value:
            _fail(f"{where}.subcarrier_offsets_hz", "expected a non-empty list of offsets in Hz")
        offsets = np.array([_number(v, f"{where}.subcarrier_offsets_hz[{i}]") for i, v in enumerate(value)])
        if np.any(np.diff(offsets) <= 0):
            _fail(f"{where}.subcarrier_offsets_hz", "must be strictly ascending")
    else:
        offsets = uniform_subcarriers(subcarriers, bandwidth_hz)
    if np.any(carrier_hz + offsets <= 0):
        _fail(f"{where}.subcarrier_offsets_hz", "every absolute frequency fc + Δf must be positive")
    return Radar(float(carrier_hz), offsets.astype(float), tx_m, rx_m)


_MATERIAL_KEYS = {"relative_permittivity", "thickness_m", "layers", "conductor"}


def _read_material(name, spec, where):
    spec = _mapping(spec, where, _MATERIAL_KEYS)
    if spec.get("conductor"):
        _bool(spec["conductor"], f"{where}.conductor")
        if "layers" in spec or "relative_permittivity" in spec:
            _fail(f"{where}.conductor", "a conductor has no permittivity or layers")
        return Material(name, (), True, _get(spec, "thickness_m", 0.002, _number, where, lo=0.0, lo_open=True))
    if "layers" in spec:
        if "relative_permittivity" in spec:
            _fail(f"{where}.layers", "give layers or relative_permittivity, not both")
        layers_spec = spec["layers"]
        if not isinstance(layers_spec, list) or not layers_spec:
            _fail(f"{where}.layers", "expected a list of {relative_permittivity, thickness_m}, front to back")
        layers = []
        for i, layer in enumerate(layers_spec):
            lw = f"{where}.layers[{i}]"
            layer = _mapping(layer, lw, {"relative_permittivity", "thickness_m"})
            for key in ("relative_permittivity", "thickness_m"):
                if key not in layer:
                    _fail(f"{lw}.{key}", "missing")
            layers.append((_permittivity(layer["relative_permittivity"], f"{lw}.relative_permittivity"),
                           _number(layer["thickness_m"], f"{lw}.thickness_m", lo=0.0, lo_open=True)))
        return Material(name, tuple(layers))
    for key in ("relative_permittivity", "thickness_m"):
        if key not in spec:
            _fail(f"{where}.{key}", "missing (or give layers, or conductor: true)")
    eps = _permittivity(spec["relative_permittivity"], f"{where}.relative_permittivity")
    return Material(name, ((eps, _number(spec["thickness_m"], f"{where}.thickness_m", lo=0.0, lo_open=True)),))


def _permittivity(value, where):
    eps = _complex(value, where)
    if eps.real < 1.0:
        _fail(where, f"the real part must be >= 1, got {eps.real}")
    if eps.imag > 0.0:
        _fail(where, f"a lossy material has a negative imaginary part (e^(+jωt) convention), got {eps}")
    return eps


def _read_materials(section):
    materials = dict(MATERIAL_PRESETS)
    if section is None:
        return materials
    if not isinstance(section, dict):
        _fail("materials", f"expected a mapping of name: material, got {_short(section)}")
    for name, spec in section.items():
        materials[str(name)] = _read_material(str(name), spec, f"materials.{name}")
    return materials


_WALL_KEYS = {"name", "segment", "material", "thickness_m"}


def _material_ref(value, materials, where, inline_name):
    """A material by preset/scene name, or an inline material mapping."""
    if isinstance(value, str):
        if value not in materials:
            _fail(where, f"unknown material '{value}'; known: {', '.join(sorted(materials))}")
        return materials[value]
    return _read_material(inline_name, value, where)


def _read_walls(section, materials):
    if section is None:
        return []
    if not isinstance(section, list):
        _fail("walls", f"expected a list of walls, got {_short(section)}")
    walls = []
    names = set()
    for i, spec in enumerate(section):
        where = f"walls[{i}]"
        spec = _mapping(spec, where, _WALL_KEYS)
        if "segment" not in spec:
            _fail(f"{where}.segment", "missing: the wall's centre line [[x1, y1], [x2, y2]] in metres")
        segment = _points(spec["segment"], f"{where}.segment", min_count=2)
        if segment.shape[0] != 2:
            _fail(f"{where}.segment", f"expected exactly two points, got {segment.shape[0]}")
        if np.hypot(*(segment[1] - segment[0])) < 1e-3:
            _fail(f"{where}.segment", "the two points coincide")
        name = str(spec.get("name", f"wall{i}"))
        if name in names:
            _fail(f"{where}.name", f"duplicate wall name '{name}'")
        names.add(name)
        material = _material_ref(spec.get("material", "plasterboard"), materials, f"{where}.material",
                                 f"{name}_material")
        if spec.get("thickness_m") is not None:
            thickness = _number(spec["thickness_m"], f"{where}.thickness_m", lo=0.0, lo_open=True)
            try:
                material = material.with_thickness(thickness)
            except ValueError as err:
                _fail(f"{where}.thickness_m", str(err))
        walls.append(Wall(i, name, segment[0], segment[1], material))
    return walls


def _wall_ref(value, walls, where):
    if isinstance(value, str):
        for wall in walls:
            if wall.name == value:
                return wall.index
        _fail(where, f"no wall named '{value}'")
    index = _number(value, where, lo=0, integer=True)
    if index >= len(walls):
        _fail(where, f"wall index {index} out of range (the scene has {len(walls)} walls)")
    return index


def _read_doors(section, walls, materials):
    if section is None:
        return []
    if not isinstance(section, list):
        _fail("doors", f"expected a list of doors, got {_short(section)}")
    doors = []
    for i, spec in enumerate(section):
        where = f"doors[{i}]"
        spec = _mapping(spec, where, {"wall", "position_m", "width_m", "material"})
        for key in ("wall", "position_m", "width_m"):
            if key not in spec:
                _fail(f"{where}.{key}", "missing")
        wall_index = _wall_ref(spec["wall"], walls, f"{where}.wall")
        position = _number(spec["position_m"], f"{where}.position_m")
        width = _number(spec["width_m"], f"{where}.width_m", lo=0.0, lo_open=True)
        length = walls[wall_index].length_m
        if position - width / 2 < -1e-9 or position + width / 2 > length + 1e-9:
            _fail(f"{where}.position_m", f"the door [{position - width / 2:g}, {position + width / 2:g}] m "
                  f"does not fit on wall '{walls[wall_index].name}' of length {length:g} m")
        material = None
        if spec.get("material") is not None:
            material = _material_ref(spec["material"], materials, f"{where}.material", f"door{i}_material")
        doors.append(Door(wall_index, float(position), float(width), material))
    # Overlapping doors on one wall are almost certainly a typo.
    for a in range(len(doors)):
        for b in range(a + 1, len(doors)):
            da, db = doors[a], doors[b]
            if da.wall_index == db.wall_index and abs(da.position_m - db.position_m) < (da.width_m + db.width_m) / 2:
                _fail(f"doors[{b}]", f"overlaps doors[{a}] on the same wall")
    return doors


def _read_clutter(section, rng):
    if section is None:
        return [], np.zeros((0, 2)), np.zeros(0, dtype=complex)
    if not isinstance(section, list):
        _fail("clutter", f"expected a list of point scatterers, got {_short(section)}")
    names, positions, amplitudes = [], [], []
    # One draw per item whether or not a phase is given, so that editing one item's phase
    # leaves the others' random phases unchanged.
    random_phases = rng.uniform(0.0, 2.0 * np.pi, size=len(section))
    for i, spec in enumerate(section):
        where = f"clutter[{i}]"
        spec = _mapping(spec, where, {"name", "position_m", "rcs_m2", "preset", "phase_deg"})
        if "position_m" not in spec:
            _fail(f"{where}.position_m", "missing")
        positions.append(_point(spec["position_m"], f"{where}.position_m"))
        if "rcs_m2" in spec and "preset" in spec:
            _fail(f"{where}.rcs_m2", "give rcs_m2 or preset, not both")
        if "rcs_m2" in spec:
            rcs = _number(spec["rcs_m2"], f"{where}.rcs_m2", lo=0.0)
        elif "preset" in spec:
            preset = spec["preset"]
            if preset not in CLUTTER_PRESETS:
                _fail(f"{where}.preset", f"unknown preset {_short(preset)}; known: {', '.join(sorted(CLUTTER_PRESETS))}")
            rcs = CLUTTER_PRESETS[preset]
        else:
            _fail(f"{where}.rcs_m2", "missing (or give a preset)")
        phase = random_phases[i]
        if spec.get("phase_deg") is not None:
            phase = math.radians(_number(spec["phase_deg"], f"{where}.phase_deg"))
        names.append(str(spec.get("name", spec.get("preset", f"clutter{i}"))))
        amplitudes.append(math.sqrt(rcs / (4.0 * math.pi)) * np.exp(1j * phase))
    return names, np.array(positions).reshape(-1, 2), np.array(amplitudes, dtype=complex)


def _read_trajectory(section):
    where = "trajectory"
    section = _mapping(section, where, {"waypoints", "step_m", "heading_deg", "poses", "poses_deg"})
    given = [k for k in ("waypoints", "poses", "poses_deg") if k in section]
    if len(given) != 1:
        _fail(where, "give exactly one of waypoints (+ step_m), poses [[x, y, heading_rad]] "
              "or poses_deg [[x, y, heading_deg]]")
    if given[0] in ("poses", "poses_deg"):
        key = given[0]
        value = section[key]
        if not isinstance(value, list) or not value:
            _fail(f"{where}.{key}", "expected a non-empty list of [x, y, heading]")
        poses = []
        for i, pose in enumerate(value):
            if not isinstance(pose, (list, tuple)) or len(pose) != 3:
                _fail(f"{where}.{key}[{i}]", f"expected [x, y, heading], got {_short(pose)}")
            poses.append([_number(v, f"{where}.{key}[{i}][{j}]") for j, v in enumerate(pose)])
        poses = np.array(poses, dtype=float)
        if key == "poses_deg":
            poses[:, 2] = np.radians(poses[:, 2])
        return poses
    waypoints = _points(section["waypoints"], f"{where}.waypoints", min_count=1)
    if waypoints.shape[0] == 1:
        heading = math.radians(_get(section, "heading_deg", 0.0, _number, where))
        return np.array([[waypoints[0, 0], waypoints[0, 1], heading]])
    if "step_m" not in section:
        _fail(f"{where}.step_m", "missing: the distance between poses along the waypoints")
    step_m = _number(section["step_m"], f"{where}.step_m", lo=0.0, lo_open=True)
    legs = np.diff(waypoints, axis=0)
    leg_lengths = np.hypot(legs[:, 0], legs[:, 1])
    if np.any(leg_lengths < 1e-9):
        _fail(f"{where}.waypoints", "two consecutive waypoints coincide")
    cumulative = np.concatenate(([0.0], np.cumsum(leg_lengths)))
    total = cumulative[-1]
    # Poses every step_m of arc length from the first waypoint; the last may fall short of
    # the end (a 1e-9 slack keeps an exact multiple).
    arc = np.arange(0.0, total + 1e-9, step_m)
    leg = np.clip(np.searchsorted(cumulative, arc, side="right") - 1, 0, len(legs) - 1)
    frac = (arc - cumulative[leg]) / leg_lengths[leg]
    xy = waypoints[leg] + frac[:, None] * legs[leg]
    if "heading_deg" in section:
        heading = np.full(arc.size, math.radians(_number(section["heading_deg"], f"{where}.heading_deg")))
    else:
        heading = np.arctan2(legs[leg, 1], legs[leg, 0])  # the robot faces its direction of travel
    return np.column_stack((xy, heading))


_NULL_KEYS = {"mode", "main_lobe_deg", "wavefront", "null_depth_db", "max_nulls", "design_band", "weights"}


def _read_tx_weights(section, num_tx):
    where = "tx_weights"
    if section is None or section == "ones":
        return {"mode": "ones"}
    if isinstance(section, list):
        section = {"mode": "explicit", "weights": section}
    section = _mapping(section, where, _NULL_KEYS)
    mode = section.get("mode", "ones")
    if mode == "ones":
        return {"mode": "ones"}
    if mode == "explicit":
        value = section.get("weights")
        if not isinstance(value, list) or len(value) != num_tx:
            _fail(f"{where}.weights", f"expected K={num_tx} weights [re, im], got {_short(value)}")
        weights = np.array([_complex(v, f"{where}.weights[{i}]") for i, v in enumerate(value)])
        return {"mode": "explicit", "weights": weights}
    if mode == "null_steer":
        if "main_lobe_deg" not in section:
            _fail(f"{where}.main_lobe_deg", "missing: the main lobe's direction, degrees CCW from robot +x")
        wavefront = section.get("wavefront", "spherical")
        if wavefront not in ("spherical", "plane"):
            _fail(f"{where}.wavefront", f"expected spherical or plane, got {_short(wavefront)}")
        band = section.get("design_band", "full")
        if band not in ("full", "carrier"):
            _fail(f"{where}.design_band", f"expected full or carrier, got {_short(band)}")
        return {
            "mode": "null_steer",
            "main_lobe_rad": math.radians(_number(section["main_lobe_deg"], f"{where}.main_lobe_deg")),
            "wavefront": wavefront,
            "null_depth_db": _get(section, "null_depth_db", 40.0, _number, where, lo=0.0),
            "max_nulls": _get(section, "max_nulls", max(1, num_tx - 2), _number, where, lo=1, hi=max(1, num_tx - 1),
                              integer=True),
            "design_band": band,
        }
    _fail(f"{where}.mode", f"expected ones, explicit or null_steer, got {_short(mode)}")


def _read_noise(section):
    where = "noise"
    if section is None:
        return {"power": 10.0 ** (-110.0 / 10.0)}
    if section == "none" or section is False:
        return {"power": 0.0}
    section = _mapping(section, where, {"power_db", "power", "snr_db"})
    if len(section) != 1:
        _fail(where, "give exactly one of power_db, power or snr_db")
    if "power_db" in section:
        return {"power": 10.0 ** (_number(section["power_db"], f"{where}.power_db") / 10.0)}
    if "power" in section:
        return {"power": _number(section["power"], f"{where}.power", lo=0.0)}
    return {"snr_db": _number(section["snr_db"], f"{where}.snr_db")}


def _chain_values(section, where, count, key, std_key, rng, unit_scale, uniform_ok=False):
    """Per-chain values: an explicit list, a random normal draw with a std, or none (zeros)."""
    if key in section and std_key in section:
        _fail(f"{where}.{std_key}", f"give {key} or {std_key}, not both")
    # Draw whatever is given, so that switching one quantity on leaves the others' draws alone.
    draws = rng.standard_normal(count)
    uniform = rng.uniform(-180.0, 180.0, count)
    if key in section:
        value = section[key]
        if uniform_ok and value == "uniform":
            return uniform * unit_scale
        if not isinstance(value, list) or len(value) != count:
            _fail(f"{where}.{key}", f"expected {count} numbers (one per chain), got {_short(value)}")
        return np.array([_number(v, f"{where}.{key}[{i}]") for i, v in enumerate(value)]) * unit_scale
    if std_key in section:
        return draws * _number(section[std_key], f"{where}.{std_key}", lo=0.0) * unit_scale
    return np.zeros(count)


_CHAIN_KEYS = {"gain_db", "gain_db_std", "phase_deg", "phase_deg_std", "delay_ps", "delay_ps_std"}
_IMPAIRMENT_KEYS = {"system_delay_s", "system_delay_known", "rx", "tx", "dc_offset", "dc_offset_db",
                    "rx_reference_frames", "rx_reference_amplitude", "tx_calibration_frames",
                    "tx_calibration_poses"}


def _read_chains(section, where, count, rng):
    section = _mapping(section or {}, where, _CHAIN_KEYS)
    gain_db = _chain_values(section, where, count, "gain_db", "gain_db_std", rng, 1.0)
    phase_rad = _chain_values(section, where, count, "phase_deg", "phase_deg_std", rng, math.pi / 180.0,
                              uniform_ok=True)
    delay_s = _chain_values(section, where, count, "delay_ps", "delay_ps_std", rng, 1e-12)
    return {"gain_db": gain_db, "phase_rad": phase_rad, "delay_s": delay_s}


def _read_impairments(section, radar, rng):
    where = "impairments"
    section = _mapping(section or {}, where, _IMPAIRMENT_KEYS)
    num_rx, num_tx = radar.num_rx, radar.num_tx
    rx = _read_chains(section.get("rx"), f"{where}.rx", num_rx, rng)
    tx = _read_chains(section.get("tx"), f"{where}.tx", num_tx, rng)
    dc_phases = rng.uniform(0.0, 2.0 * np.pi, num_rx)
    if "dc_offset" in section and "dc_offset_db" in section:
        _fail(f"{where}.dc_offset_db", "give dc_offset or dc_offset_db, not both")
    dc = np.zeros(num_rx, dtype=complex)
    if "dc_offset" in section:
        value = section["dc_offset"]
        if isinstance(value, list) and len(value) == num_rx and all(isinstance(v, (list, tuple, str)) for v in value):
            dc = np.array([_complex(v, f"{where}.dc_offset[{i}]") for i, v in enumerate(value)])
        else:
            dc = np.full(num_rx, _complex(value, f"{where}.dc_offset"))
    elif "dc_offset_db" in section:
        level = 10.0 ** (_number(section["dc_offset_db"], f"{where}.dc_offset_db") / 20.0)
        dc = level * np.exp(1j * dc_phases)
    rx_impaired = bool(np.any(rx["gain_db"]) or np.any(rx["phase_rad"]) or np.any(rx["delay_s"]) or np.any(dc))
    system_delay_s = _get(section, "system_delay_s", 0.0, _number, where, lo=0.0)
    return {
        "system_delay_s": float(system_delay_s),
        "system_delay_known": _get(section, "system_delay_known", True, _bool, where),
        "rx": rx,
        "tx": tx,
        "dc_offset": dc,
        "rx_impaired": rx_impaired,
        "rx_reference_frames": _get(section, "rx_reference_frames", 4 if rx_impaired else 0, _number, where, lo=0,
                                    integer=True),
        "rx_reference_amplitude": _get(section, "rx_reference_amplitude", 0.01, _number, where, lo=0.0, lo_open=True),
        # The radio's TX calibration (tx_calibration.py): frames per element, at each of the first poses.
        "tx_calibration_frames": _get(section, "tx_calibration_frames", 0, _number, where, lo=0, integer=True),
        "tx_calibration_poses": _get(section, "tx_calibration_poses", 4, _number, where, lo=1, integer=True),
    }


def _read_odometry(section):
    where = "odometry"
    keys = {"scale_error": 0.0, "heading_drift_deg_per_m": 0.0, "position_noise_m": 0.0, "heading_noise_deg": 0.0}
    section = _mapping(section or {}, where, set(keys))
    values = {key: _get(section, key, default, _number, where) for key, default in keys.items()}
    for key in ("position_noise_m", "heading_noise_deg"):
        if values[key] < 0:
            _fail(f"{where}.{key}", f"a standard deviation must be >= 0, got {values[key]}")
    return values


_PHYSICS_DEFAULTS = {
    "direct": True,
    "reflections": True,
    "second_order": True,
    "transmission": True,
    "diffuse": True,
    "edges": True,
    "clutter": True,
    "max_walls_crossed": 4,
    "max_range_m": 15.0,
    "diffuse_density_per_m": 2.0,
    "diffuse_rcs_m2": 0.01,
    "edge_rcs_m2": 0.05,
}


def _read_physics(section):
    where = "physics"
    section = _mapping(section or {}, where, set(_PHYSICS_DEFAULTS))
    physics = {}
    for key, default in _PHYSICS_DEFAULTS.items():
        if isinstance(default, bool):
            physics[key] = _get(section, key, default, _bool, where)
        elif key == "max_walls_crossed":
            physics[key] = _get(section, key, default, _number, where, lo=0, integer=True)
        else:
            physics[key] = float(_get(section, key, default, _number, where, lo=0.0))
    return physics


_TRUTH_DEFAULTS = {"max_range_m": 8.0, "max_walls_crossed": 1, "max_incidence_deg": 75.0, "sample_m": 0.05}


def _read_truth(section):
    where = "truth"
    section = _mapping(section or {}, where, set(_TRUTH_DEFAULTS))
    return {
        "max_range_m": float(_get(section, "max_range_m", 8.0, _number, where, lo=0.0, lo_open=True)),
        "max_walls_crossed": _get(section, "max_walls_crossed", 1, _number, where, lo=0, integer=True),
        "max_incidence_deg": float(_get(section, "max_incidence_deg", 75.0, _number, where, lo=0.0, hi=90.0)),
        "sample_m": float(_get(section, "sample_m", 0.05, _number, where, lo=0.0, lo_open=True)),
    }


def _read_timing(section):
    where = "timing"
    section = _mapping(section or {}, where, {"start_time", "frame_period_s"})
    start = section.get("start_time", "2024-01-01T09:00:00Z")
    if not isinstance(start, str):
        # YAML turns an unquoted timestamp into a datetime; keep its ISO text.
        start = start.isoformat() if hasattr(start, "isoformat") else start
    _string(start, f"{where}.start_time")
    return {"start_time": start,
            "frame_period_s": float(_get(section, "frame_period_s", 0.05, _number, where, lo=0.0, lo_open=True))}


_TOP_KEYS = {"name", "description", "seed", "radar", "materials", "walls", "doors", "clutter", "trajectory",
             "frames_per_pose", "tx_weights", "noise", "impairments", "odometry", "physics", "truth", "timing"}

# Independent random streams: one per purpose, so that changing one part of a scene leaves
# the random draws of the others as they were.
RNG_CLUTTER, RNG_IMPAIRMENTS, RNG_DIFFUSE, RNG_ODOMETRY, RNG_NOISE, RNG_TX_CALIBRATION = 1, 2, 3, 4, 5, 6


def rng_for(seed, purpose):
    """The scene's random stream for one purpose (RNG_* constants)."""
    return np.random.default_rng(np.random.SeedSequence([int(seed), int(purpose)]))


def load_scene(path_or_dict, *, seed=None):
    """Read and validate a scene: a YAML file path or a dict of the same shape.

    seed overrides the scene's seed. Raises SceneError naming the field on the first problem.
    """
    source_path = None
    if isinstance(path_or_dict, dict):
        data = path_or_dict
        default_name = "scene"
    else:
        import yaml

        source_path = os.fspath(path_or_dict)
        try:
            with open(source_path, "r", encoding="utf-8") as handle:
                data = yaml.safe_load(handle)
        except FileNotFoundError:
            raise SceneError(f"{source_path}: no such scene file") from None
        except yaml.YAMLError as err:
            raise SceneError(f"{source_path}: not valid YAML: {err}") from None
        default_name = os.path.basename(source_path)
        for suffix in (".yaml", ".yml"):
            if default_name.endswith(suffix):
                default_name = default_name[: -len(suffix)]
    if not isinstance(data, dict):
        raise SceneError("scene: the top level must be a mapping")
    _mapping(data, "", _TOP_KEYS)

    name = _string(str(data.get("name", default_name)), "name")
    if any(c in name for c in "/\\") or name in (".", ".."):
        _fail("name", f"must be usable as a file name, got {name!r}")
    scene_seed = _get(data, "seed", 0, _number, "", lo=0, integer=True) if seed is None else int(seed)
    radar = _read_radar(data.get("radar"))
    materials = _read_materials(data.get("materials"))
    walls = _read_walls(data.get("walls"), materials)
    doors = _read_doors(data.get("doors"), walls, materials)
    clutter_names, clutter_xy, clutter_amp = _read_clutter(data.get("clutter"), rng_for(scene_seed, RNG_CLUTTER))
    if "trajectory" not in data:
        _fail("trajectory", "missing: give waypoints + step_m, or poses")
    poses = _read_trajectory(data["trajectory"])
    frames_per_pose = _get(data, "frames_per_pose", 4, _number, "", lo=1, integer=True)
    tx_weights = _read_tx_weights(data.get("tx_weights"), radar.num_tx)
    impairments = _read_impairments(data.get("impairments"), radar, rng_for(scene_seed, RNG_IMPAIRMENTS))
    scene = Scene(
        name=name,
        description=str(data.get("description", "")),
        seed=scene_seed,
        radar=radar,
        walls=walls,
        doors=doors,
        clutter_names=clutter_names,
        clutter_position_m=clutter_xy,
        clutter_amplitude_m=clutter_amp,
        poses=poses,
        frames_per_pose=frames_per_pose,
        tx_weights=tx_weights,
        noise=_read_noise(data.get("noise")),
        impairments=impairments,
        odometry=_read_odometry(data.get("odometry")),
        physics=_read_physics(data.get("physics")),
        truth=_read_truth(data.get("truth")),
        timing=_read_timing(data.get("timing")),
        source_path=source_path,
        materials=materials,
    )
    _check_clearance(scene)
    return scene


def _check_clearance(scene):
    """Every antenna element at every pose must lie outside every wall's material."""
    if not scene.walls:
        return
    elements = np.vstack((scene.radar.tx_elements_m, scene.radar.rx_elements_m))  # (E, 2) robot
    cos_h, sin_h = np.cos(scene.poses[:, 2]), np.sin(scene.poses[:, 2])
    world = np.stack((
        scene.poses[:, None, 0] + cos_h[:, None] * elements[None, :, 0] - sin_h[:, None] * elements[None, :, 1],
        scene.poses[:, None, 1] + sin_h[:, None] * elements[None, :, 0] + cos_h[:, None] * elements[None, :, 1],
    ), axis=-1).reshape(-1, 2)
    for wall in scene.walls:
        direction = (wall.end_m - wall.start_m) / wall.length_m
        rel = world - wall.start_m
        along = rel @ direction
        across = np.abs(rel @ np.array([-direction[1], direction[0]]))
        inside = (along > 0) & (along < wall.length_m) & (across < wall.thickness_m / 2)
        if np.any(inside):
            pose = int(np.flatnonzero(inside)[0] // elements.shape[0])
            _fail("trajectory", f"at pose {pose} {scene.poses[pose].tolist()} an antenna element is inside "
                  f"wall '{wall.name}' (walls[{wall.index}])")


def describe(scene):
    """A few lines that summarise a scene (for the CLI)."""
    r = scene.radar
    offsets = r.subcarrier_offsets_hz
    spacing_hz = float(np.median(np.diff(offsets))) if offsets.size > 1 else 0.0
    lines = [
        f"scene '{scene.name}': {len(scene.walls)} walls, {len(scene.doors)} doors, "
        f"{len(scene.clutter_names)} clutter points, {scene.num_poses} poses x {scene.frames_per_pose} frames",
        f"radar: K={r.num_tx} TX, M={r.num_rx} RX, N={r.num_subcarriers} subcarriers at "
        f"{r.carrier_hz / 1e9:.4g} GHz, spacing {spacing_hz / 1e3:.4g} kHz (N x spacing = "
        f"{offsets.size * spacing_hz / 1e6:.4g} MHz), "
        f"array centres {np.round(r.tx_centre_m, 3).tolist()} / {np.round(r.rx_centre_m, 3).tolist()} m",
        f"tx weights: {scene.tx_weights['mode']}; seed {scene.seed}",
    ]
    return "\n".join(lines)
