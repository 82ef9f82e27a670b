#
# SPDX-License-Identifier: GPL-3.0-or-later
#
"""Scoring a map against the ground truth: both GeoJSON maps per FORMATS.md.

Per class (line_of_sight, hidden):
- detection error: distance from every point of the map's "detections" MultiPoints of that
  class to the nearest true wall face of that class: RMS, median, count;
- coverage: the length of true wall face of that class that lies within coverage_tolerance_m
  (0.3 m) of some map wall (of any class: a wall found is a wall found), and its fraction;
- false wall length: map wall length farther than false_tolerance_m (0.5 m) from every true
  wall face;
and overall: true corners with a map corner within corner_tolerance_m (0.5 m), map corners
near no true corner, open doorways ("kind": "opening", the project's own feature) found
within opening_tolerance_m (0.5 m) of a true one's middle and their jambs' error, and the
trajectory error (pointwise RMS when the map's trajectory has as
many points as the truth's; otherwise the RMS distance of its points to the true path, flagged).
"missed_walls" lists each true wall feature with at least MISSED_MIN_M of its face uncovered,
worst first: its name (thrumapper-sim's truth names every wall), class, length, the length
uncovered and where the uncovered stretch begins and ends, so a low coverage says which walls.
"error_sources" (per class, under "detections") says where a large RMS comes from: the
detections farther than coverage_tolerance_m from every true wall of their class, grouped by
why: "other_class" (within the tolerance of a true wall of the other class: a wall found in
the wrong class, a room's back wall seen through an open door mapped hidden) or "off_wall"
(near no true wall of either class: a misplaced or ghost wall), and by the true wall they are
nearest to, worst first, with the share of the class's squared detection error each carries.
A map whose RMS is a few wrong-class detections needs a different fix from one whose every
detection is 10 cm off.

Lengths are measured by sampling every line at sample_m (1 cm) and weighting each sample by
the length it stands for, so partial coverage of a segment is counted to the centimetre.
"""

import json
import math
import os
from dataclasses import dataclass, field

import numpy as np

CLASSES = ("line_of_sight", "hidden")
CRS = "local-metres"


class MapFormatError(ValueError):
    """A map or truth file that breaks FORMATS.md; the message names what is wrong and where."""


@dataclass(eq=False)
class MapData:
    """The features of a map that scoring uses, as numpy arrays (world metres)."""

    label: str
    walls: list = field(default_factory=list)  # dicts: coordinates (n, 2), class, confidence, name (or None)
    detections: list = field(default_factory=list)  # dicts: points (n, 2), class
    corners: list = field(default_factory=list)  # dicts: position (2,), confidence, class (or None)
    openings: list = field(default_factory=list)  # (2, 2) arrays: an open doorway's two ends
    trajectory: np.ndarray = None  # (T, 2) or None


# ----------------------------------------------------------------------------------------
# Reading and checking
# ----------------------------------------------------------------------------------------
def _short(value, limit=60):
    text = json.dumps(value) if _jsonable(value) else repr(value)
    return text if len(text) <= limit else text[: limit - 3] + "..."


def _jsonable(value):
    try:
        json.dumps(value)
        return True
    except (TypeError, ValueError):
        return False


def _position(value, where):
    if (
        not isinstance(value, list)
        or len(value) < 2
        or not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in value)
        or not all(math.isfinite(v) for v in value)
    ):
        raise MapFormatError(f"{where}: expected a position [x, y] of finite numbers (metres), got {_short(value)}")
    return value[:2]  # a third coordinate (height) is allowed by GeoJSON and ignored


def _positions(value, where, minimum):
    if not isinstance(value, list):
        raise MapFormatError(f"{where}: expected a list of positions [x, y], got {_short(value)}")
    if len(value) < minimum:
        raise MapFormatError(f"{where}: expected at least {minimum} positions, got {len(value)}")
    return np.array([_position(p, f"{where}[{i}]") for i, p in enumerate(value)], dtype=float).reshape(-1, 2)


def _geometry(feature, where, expected):
    geometry = feature.get("geometry")
    if not isinstance(geometry, dict):
        raise MapFormatError(f"{where}.geometry: expected a {expected} geometry object, got {_short(geometry)}")
    kind = geometry.get("type")
    if kind != expected:
        raise MapFormatError(f"{where}.geometry.type: expected \"{expected}\", got {_short(kind)}")
    if "coordinates" not in geometry:
        raise MapFormatError(f"{where}.geometry.coordinates: missing")
    coordinates = geometry["coordinates"]
    where = f"{where}.geometry.coordinates"
    if expected == "Point":
        return np.array(_position(coordinates, where), dtype=float)
    return _positions(coordinates, where, 2 if expected == "LineString" else 0)


def _class(properties, where, required=True):
    if "class" not in properties:
        if required:
            raise MapFormatError(f"{where}.properties.class: missing; expected one of {', '.join(CLASSES)}")
        return None
    value = properties["class"]
    if value not in CLASSES:
        raise MapFormatError(f"{where}.properties.class: expected one of {', '.join(CLASSES)}, got {_short(value)}")
    return value


def _confidence(properties, where):
    if "confidence" not in properties:
        raise MapFormatError(f"{where}.properties.confidence: missing; expected a number from 0 to 1")
    value = properties["confidence"]
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not 0.0 <= value <= 1.0:
        raise MapFormatError(f"{where}.properties.confidence: expected a number from 0 to 1, got {_short(value)}")
    return float(value)


def load_map(source, label=None):
    """Read and check a map GeoJSON (a path or an already parsed dict). Returns MapData.

    Raises MapFormatError naming the file, the feature and the field on the first problem.
    Features of kinds this reader does not know are ignored, as FORMATS.md asks.
    """
    if isinstance(source, dict):
        data = source
        label = label or "map"
    else:
        path = os.fspath(source)
        label = label or path
        try:
            with open(path, "r", encoding="utf-8") as handle:
                data = json.load(handle)
        except FileNotFoundError:
            raise MapFormatError(f"{label}: no such file") from None
        except (json.JSONDecodeError, UnicodeDecodeError) as err:
            raise MapFormatError(f"{label}: not valid JSON: {err}") from None
    if not isinstance(data, dict):
        raise MapFormatError(f"{label}: the top level must be a GeoJSON object, got {_short(data)}")
    if data.get("type") != "FeatureCollection":
        raise MapFormatError(f"{label}: type: expected \"FeatureCollection\", got {_short(data.get('type'))}")
    if data.get("thrumapper:crs") != CRS:
        raise MapFormatError(
            f"{label}: thrumapper:crs: expected \"{CRS}\" (coordinates in world-frame metres), "
            f"got {_short(data.get('thrumapper:crs'))}")
    features = data.get("features")
    if not isinstance(features, list):
        raise MapFormatError(f"{label}: features: expected a list of Feature objects, got {_short(features)}")
    result = MapData(label=label)
    for i, feature in enumerate(features):
        where = f"{label}: features[{i}]"
        if not isinstance(feature, dict) or feature.get("type") != "Feature":
            raise MapFormatError(f"{where}: expected a GeoJSON Feature object with \"type\": \"Feature\"")
        properties = feature.get("properties")
        if properties is None:
            continue  # no kind: nothing this reader knows
        if not isinstance(properties, dict):
            raise MapFormatError(f"{where}.properties: expected an object, got {_short(properties)}")
        kind = properties.get("kind")
        where = f"{where} (kind {kind!r})" if kind is not None else where
        if kind == "wall":
            result.walls.append({
                "coordinates": _geometry(feature, where, "LineString"),
                "class": _class(properties, where),
                "confidence": _confidence(properties, where),
                "name": properties["name"] if isinstance(properties.get("name"), str) else None,
            })
        elif kind == "detections":
            result.detections.append({
                "points": _geometry(feature, where, "MultiPoint"),
                "class": _class(properties, where),
            })
        elif kind == "corner":
            result.corners.append({
                "position": _geometry(feature, where, "Point"),
                "confidence": _confidence(properties, where),
                "class": _class(properties, where, required=False),
            })
        elif kind == "opening":  # an open doorway (not in FORMATS.md's list: the project's own)
            ends = _geometry(feature, where, "LineString")
            result.openings.append(np.vstack((ends[0], ends[-1])))
        elif kind == "trajectory":
            if result.trajectory is not None:
                raise MapFormatError(f"{where}: a second trajectory feature; a map has one")
            result.trajectory = _geometry(feature, where, "LineString")
    return result


# ----------------------------------------------------------------------------------------
# Geometry
# ----------------------------------------------------------------------------------------
def _segments(polylines):
    """All consecutive-point segments of a list of (n, 2) polylines: (S, 2), (S, 2)."""
    starts = [p[:-1] for p in polylines if p.shape[0] >= 2]
    ends = [p[1:] for p in polylines if p.shape[0] >= 2]
    if not starts:
        return np.zeros((0, 2)), np.zeros((0, 2))
    return np.vstack(starts), np.vstack(ends)


def distance_to_segments(points, seg_start, seg_end, chunk=4096):
    """Distance from each point (Q, 2) to the nearest segment; +inf when there are none."""
    points = np.asarray(points, dtype=float).reshape(-1, 2)
    out = np.full(points.shape[0], np.inf)
    if seg_start.shape[0] == 0:
        return out
    d = seg_end - seg_start
    length2 = np.maximum(np.einsum("sd,sd->s", d, d), 1e-24)
    for begin in range(0, points.shape[0], chunk):
        p = points[begin : begin + chunk]
        rel = p[:, None, :] - seg_start[None, :, :]
        t = np.clip(np.einsum("qsd,sd->qs", rel, d) / length2, 0.0, 1.0)
        gap = rel - t[..., None] * d[None, :, :]
        out[begin : begin + chunk] = np.sqrt(np.min(np.einsum("qsd,qsd->qs", gap, gap), axis=1))
    return out


def _sample(polylines, sample_m):
    """Points along polylines every ≤ sample_m, with the length each stands for."""
    points, weights = [], []
    for line in polylines:
        for a, b in zip(line[:-1], line[1:]):
            length = float(np.hypot(*(b - a)))
            if length <= 0.0:
                continue
            count = max(1, int(math.ceil(length / sample_m)))
            t = (np.arange(count) + 0.5) / count
            points.append(a + t[:, None] * (b - a))
            weights.append(np.full(count, length / count))
    if not points:
        return np.zeros((0, 2)), np.zeros(0)
    return np.vstack(points), np.concatenate(weights)


def _stats(distances):
    if distances.size == 0:
        return {"count": 0, "rms_m": None, "median_m": None, "max_m": None}
    return {
        "count": int(distances.size),
        "rms_m": float(np.sqrt(np.mean(distances**2))),
        "median_m": float(np.median(distances)),
        "max_m": float(np.max(distances)),
    }


# ----------------------------------------------------------------------------------------
# Scoring
# ----------------------------------------------------------------------------------------
def _nearest_wall(points, walls):
    """For each point (Q, 2): the distance to the nearest of `walls` (truth wall dicts) and
    that wall's index (-1 when there are none)."""
    best = np.full(points.shape[0], np.inf)
    which = np.full(points.shape[0], -1)
    for i, wall in enumerate(walls):
        d = distance_to_segments(points, *_segments([wall["coordinates"]]))
        closer = d < best
        best[closer], which[closer] = d[closer], i
    return best, which


def _error_sources(points, distances, cls, truth_walls, tolerance_m):
    """Where the squared detection error of one class comes from (see the module's
    docstring): [{"why", "wall", "count", "share", "rms_m"}], worst first."""
    total = float(np.sum(distances ** 2))
    far = np.flatnonzero(distances > tolerance_m)
    if far.size == 0 or total <= 0.0:
        return []
    same = [w for w in truth_walls if w["class"] == cls]
    other = [w for w in truth_walls if w["class"] != cls]
    to_other, other_wall = _nearest_wall(points[far], other)
    _, same_wall = _nearest_wall(points[far], same)
    groups = {}
    for n, i in enumerate(far):
        if to_other[n] <= tolerance_m:
            key = ("other_class", other[other_wall[n]].get("name"))
        else:
            key = ("off_wall", same[same_wall[n]].get("name") if same_wall[n] >= 0 else None)
        groups.setdefault(key, []).append(distances[i])
    out = [{"why": why, "wall": name, "count": len(d), "share": float(np.sum(np.square(d)) / total),
            "rms_m": float(np.sqrt(np.mean(np.square(d))))} for (why, name), d in groups.items()]
    return sorted(out, key=lambda e: -e["share"])


def _score_openings(ours, true, tolerance_m):
    """Open doorways: a true one is found when a map opening's middle lies within
    tolerance_m of its middle (each map opening counts once); for those found, the RMS
    distance of the map opening's two ends to the true one's (its jambs)."""
    out = {"truth": len(true), "map": len(ours), "found": 0, "fraction": None, "unmatched_map": len(ours),
           "jamb_error_rms_m": None}
    if not true:
        return out
    free = list(range(len(ours)))
    jambs = []
    for t in true:
        if not free:
            break
        gaps = [float(np.hypot(*(ours[i].mean(axis=0) - t.mean(axis=0)))) for i in free]
        best = int(np.argmin(gaps))
        if gaps[best] <= tolerance_m:
            o = ours[free.pop(best)]
            same, swapped = np.hypot(*(o - t).T), np.hypot(*(o[::-1] - t).T)  # either way round
            jambs += (same if np.sum(same ** 2) <= np.sum(swapped ** 2) else swapped).tolist()
            out["found"] += 1
    out["fraction"] = out["found"] / len(true)
    out["unmatched_map"] = len(free)
    if jambs:
        out["jamb_error_rms_m"] = float(np.sqrt(np.mean(np.square(jambs))))
    return out


#: a true wall is listed in "missed_walls" when at least this much of it is uncovered (m)
MISSED_MIN_M = 0.1


def _wall_coverage(truth_walls, map_start, map_end, coverage_tolerance_m, sample_m):
    """Each true wall's samples, their weights and whether a map wall covers them: one
    (samples, weights, covered) a wall, in order (the class coverage and the missed walls
    both read these)."""
    out = []
    for wall in truth_walls:
        samples, weights = _sample([wall["coordinates"]], sample_m)
        out.append((samples, weights, distance_to_segments(samples, map_start, map_end) <= coverage_tolerance_m))
    return out


def _missed_walls(truth_walls, coverage):
    """The true walls with uncovered face, worst first (see the module's docstring);
    coverage: _wall_coverage's of the same walls."""
    missed = []
    for wall, (samples, weights, covered) in zip(truth_walls, coverage):
        if samples.shape[0] == 0:
            continue
        uncovered = ~covered
        uncovered_m = float(weights[uncovered].sum())
        if uncovered_m < MISSED_MIN_M:
            continue
        idx = np.flatnonzero(uncovered)
        missed.append({"name": wall.get("name"), "class": wall["class"], "length_m": float(weights.sum()),
                       "uncovered_m": uncovered_m,
                       "uncovered_from": [float(v) for v in samples[idx[0]]],
                       "uncovered_to": [float(v) for v in samples[idx[-1]]]})
    missed.sort(key=lambda m: -m["uncovered_m"])
    return missed


def align_to_truth(map_data, truth_data):
    """The map moved by the rigid move (a turn and a shift, no scale) that puts its trajectory
    closest to the truth's, pose by pose in the least-squares sense (Umeyama's closed form,
    as SLAM benchmarks align a trajectory before its absolute error): what is left is the
    map's shape, its frame taken out. A map is drawn in the frame of its first pose, and in
    a straight corridor little but that pose holds the whole map's rotation, so the plain
    scores carry the frame's error too; a map registered on a surveyed plan drops it.

    Returns (MapData moved, {"rotation_deg", "shift_m": [x, y], "poses"}). Raises
    MapFormatError when either file has no trajectory or they differ in length (the
    move needs them pose by pose)."""
    if not isinstance(map_data, MapData):
        map_data = load_map(map_data, "map")
    if not isinstance(truth_data, MapData):
        truth_data = load_map(truth_data, "truth")
    for data in (map_data, truth_data):
        if data.trajectory is None:
            raise MapFormatError(f"{data.label}: no trajectory feature: aligning needs the map's and the truth's")
    ours, true = map_data.trajectory, truth_data.trajectory
    if ours.shape[0] != true.shape[0] or ours.shape[0] < 2:
        raise MapFormatError(f"{map_data.label}: its trajectory has {ours.shape[0]} poses and the truth's "
                             f"{true.shape[0]}: aligning pairs them pose by pose (at least 2)")
    mean_ours, mean_true = ours.mean(axis=0), true.mean(axis=0)
    u, _, vt = np.linalg.svd((ours - mean_ours).T @ (true - mean_true))
    flip = np.diag([1.0, np.sign(np.linalg.det(vt.T @ u.T)) or 1.0])  # a turn, not a mirror
    rotation = vt.T @ flip @ u.T
    shift = mean_true - rotation @ mean_ours

    def move(points):
        return np.asarray(points, float) @ rotation.T + shift

    moved = MapData(
        label=map_data.label,
        walls=[dict(w, coordinates=move(w["coordinates"])) for w in map_data.walls],
        detections=[dict(d, points=move(d["points"])) for d in map_data.detections],
        corners=[dict(c, position=move(c["position"])) for c in map_data.corners],
        openings=[move(o) for o in map_data.openings],
        trajectory=move(ours))
    return moved, {"rotation_deg": float(np.degrees(np.arctan2(rotation[1, 0], rotation[0, 0]))),
                   "shift_m": [float(shift[0]), float(shift[1])], "poses": int(ours.shape[0])}


def score_map(map_data, truth_data, *, coverage_tolerance_m=0.3, false_tolerance_m=0.5, corner_tolerance_m=0.5,
              sample_m=0.01, opening_tolerance_m=0.5):
    """Score a map against the truth (MapData, or anything load_map takes). Returns a dict
    of plain numbers (None where a quantity does not exist), ready for json.dumps."""
    if not isinstance(map_data, MapData):
        map_data = load_map(map_data, "map")
    if not isinstance(truth_data, MapData):
        truth_data = load_map(truth_data, "truth")
    map_lines = [w["coordinates"] for w in map_data.walls]
    map_start, map_end = _segments(map_lines)
    all_truth_start, all_truth_end = _segments([w["coordinates"] for w in truth_data.walls])
    scored_walls = [w for w in truth_data.walls if w["class"] in CLASSES]
    coverage = _wall_coverage(scored_walls, map_start, map_end, coverage_tolerance_m, sample_m)

    classes = {}
    for cls in CLASSES:
        truth_lines = [w["coordinates"] for w in truth_data.walls if w["class"] == cls]
        t_start, t_end = _segments(truth_lines)
        points = [d["points"] for d in map_data.detections if d["class"] == cls]
        points = np.vstack(points) if points else np.zeros((0, 2))
        distances = distance_to_segments(points, t_start, t_end) if t_start.shape[0] else np.zeros(0)
        detection = _stats(distances)
        if t_start.shape[0] == 0:
            detection["note"] = "the truth has no wall of this class"
        else:
            detection["error_sources"] = _error_sources(points, distances, cls, truth_data.walls,
                                                        coverage_tolerance_m)
        mine = [c for w, c in zip(scored_walls, coverage) if w["class"] == cls]
        weights = np.concatenate([c[1] for c in mine]) if mine else np.zeros(0)
        covered = np.concatenate([c[2] for c in mine]) if mine else np.zeros(0, bool)
        truth_length = float(weights.sum())
        covered_length = float(weights[covered].sum())
        map_samples, map_weights = _sample([w["coordinates"] for w in map_data.walls if w["class"] == cls], sample_m)
        far = distance_to_segments(map_samples, all_truth_start, all_truth_end) > false_tolerance_m
        classes[cls] = {
            "detections": detection,
            "truth_wall_length_m": truth_length,
            "covered_length_m": covered_length,
            "coverage": covered_length / truth_length if truth_length > 0 else None,
            "map_wall_length_m": float(map_weights.sum()),
            "false_wall_length_m": float(map_weights[far].sum()),
        }

    truth_corners = np.array([c["position"] for c in truth_data.corners]).reshape(-1, 2)
    map_corners = np.array([c["position"] for c in map_data.corners]).reshape(-1, 2)
    corners = {"truth": int(truth_corners.shape[0]), "map": int(map_corners.shape[0]), "found": 0,
               "fraction": None, "unmatched_map": int(map_corners.shape[0])}
    if truth_corners.shape[0] and map_corners.shape[0]:
        gaps = np.hypot(*(truth_corners[:, None, :] - map_corners[None, :, :]).transpose(2, 0, 1))
        corners["found"] = int(np.sum(gaps.min(axis=1) <= corner_tolerance_m))
        corners["unmatched_map"] = int(np.sum(gaps.min(axis=0) > corner_tolerance_m))
    if truth_corners.shape[0]:
        corners["fraction"] = corners["found"] / truth_corners.shape[0]

    openings = _score_openings(map_data.openings, truth_data.openings, opening_tolerance_m)

    trajectory = None
    if map_data.trajectory is not None and truth_data.trajectory is not None:
        ours, true = map_data.trajectory, truth_data.trajectory
        if ours.shape[0] == true.shape[0]:
            error = np.hypot(*(ours - true).T)
            trajectory = {"pointwise": True, **_stats(error)}
        else:
            # Different sampling: how far the map's poses are from the true path.
            error = distance_to_segments(ours, *_segments([true]))
            trajectory = {"pointwise": False, **_stats(error),
                          "note": f"map has {ours.shape[0]} points, truth {true.shape[0]}: distances to the true path"}

    total_false = sum(c["false_wall_length_m"] for c in classes.values())
    missed = _missed_walls(scored_walls, coverage)
    return {
        "map": map_data.label,
        "truth": truth_data.label,
        "classes": classes,
        "false_wall_length_m": float(total_false),
        "map_wall_length_m": float(sum(c["map_wall_length_m"] for c in classes.values())),
        "corners": corners,
        "openings": openings,
        "trajectory": trajectory,
        "missed_walls": missed,
        "tolerances_m": {"coverage": coverage_tolerance_m, "false_wall": false_tolerance_m,
                         "corner": corner_tolerance_m, "sample": sample_m, "opening": opening_tolerance_m},
    }


def _fmt(value, unit="", scale=1.0, digits=3):
    if value is None:
        return "-"
    return f"{value * scale:.{digits}f}{unit}"


def format_table(scores, missed=5, sources=3):
    """The scores as a readable plain-text table; `missed`: how many of the most uncovered
    true walls to list (0: none); `sources`: how many of each class's largest error sources
    (0: none)."""
    tol = scores["tolerances_m"]
    lines = [f"map:   {scores['map']}", f"truth: {scores['truth']}"]
    aligned = scores.get("aligned")
    if aligned:
        lines.append(f"aligned: the map turned {aligned['rotation_deg']:+.3f} deg and shifted "
                     f"({aligned['shift_m'][0]:+.3f}, {aligned['shift_m'][1]:+.3f}) m onto the true trajectory "
                     f"({aligned['poses']} poses) before scoring")
    lines.append("")
    header = f"{'':34s}{'line_of_sight':>16s}{'hidden':>16s}"
    lines.append(header)
    lines.append("-" * len(header))

    def row(name, getter):
        lines.append(f"{name:34s}" + "".join(f"{getter(scores['classes'][c]):>16s}" for c in CLASSES))

    row("detections", lambda c: str(c["detections"]["count"]))
    row("detection error RMS (m)", lambda c: _fmt(c["detections"]["rms_m"]))
    row("detection error median (m)", lambda c: _fmt(c["detections"]["median_m"]))
    row("true wall length (m)", lambda c: _fmt(c["truth_wall_length_m"], digits=2))
    row(f"covered within {tol['coverage']:g} m (m)", lambda c: _fmt(c["covered_length_m"], digits=2))
    row("coverage", lambda c: _fmt(c["coverage"], " %", 100.0, 1))
    row("map wall length (m)", lambda c: _fmt(c["map_wall_length_m"], digits=2))
    row(f"false wall, > {tol['false_wall']:g} m off (m)", lambda c: _fmt(c["false_wall_length_m"], digits=2))
    lines.append("")
    corners = scores["corners"]
    lines.append(f"corners found within {tol['corner']:g} m: {corners['found']} of {corners['truth']}"
                 + (f" ({corners['fraction'] * 100:.1f} %)" if corners["fraction"] is not None else "")
                 + f"; map corners matching no true corner: {corners['unmatched_map']}")
    openings = scores.get("openings")
    if openings and (openings["truth"] or openings["map"]):
        lines.append(f"open doorways found within {tol.get('opening', 0.5):g} m: {openings['found']} of "
                     f"{openings['truth']}; map openings matching none: {openings['unmatched_map']}"
                     + (f"; jamb error RMS {openings['jamb_error_rms_m']:.3f} m"
                        if openings["jamb_error_rms_m"] is not None else ""))
    lines.append(f"false wall length, all classes: {scores['false_wall_length_m']:.2f} m "
                 f"of {scores['map_wall_length_m']:.2f} m mapped")
    trajectory = scores["trajectory"]
    if trajectory is None:
        lines.append("trajectory: not in both files")
    else:
        how = "pointwise" if trajectory["pointwise"] else "to the true path"
        lines.append(f"trajectory error RMS ({how}, {trajectory['count']} points): {_fmt(trajectory['rms_m'])} m, "
                     f"max {_fmt(trajectory['max_m'])} m")
    walls = scores.get("missed_walls") or []
    if missed > 0 and walls:
        shown = walls[:missed]
        lines.append("")
        lines.append(f"true walls least covered ({len(shown)} of {len(walls)} with {MISSED_MIN_M:g} m or more "
                     f"uncovered):")
        for m in shown:
            a, b = m["uncovered_from"], m["uncovered_to"]
            lines.append(f"  {(m['name'] or '(unnamed)'):20s} {m['class']:14s} {m['uncovered_m']:5.2f} of "
                         f"{m['length_m']:5.2f} m uncovered, ({a[0]:.2f}, {a[1]:.2f}) .. ({b[0]:.2f}, {b[1]:.2f})")
    for cls in CLASSES:
        found = scores["classes"][cls]["detections"].get("error_sources") or []
        if sources > 0 and found:
            lines.append("")
            lines.append(f"{cls} detections more than {tol['coverage']:g} m off (the squared error they carry):")
            for e in found[:sources]:
                where = ("on a true wall of the other class" if e["why"] == "other_class"
                         else "near no true wall; nearest of the class")
                lines.append(f"  {e['share'] * 100:5.1f} %  {e['count']:4d} detections, RMS {e['rms_m']:.2f} m, "
                             f"{where}: {e['wall'] or '(unnamed)'}")
    return "\n".join(lines)
