#
# SPDX-License-Identifier: GPL-3.0-or-later
#
"""Live map: a QT GUI block that draws the floor plan as wall fusion builds it.

`live_map` is a message-only GNU Radio block. Its inputs:

  map    wall_fusion's "map" message (wall_fusion.map_to_pmt): walls, corners, detections,
         the (corrected) trajectory;
  pose   the robot's pose, any form survey_sink takes (a dict with "pose" f64vector
         [x, y, heading] or with x, y, heading; a bare f64vector): the robot marker and the
         trail between map updates;
  paths  jade_estimator's "paths" message: the latest echoes, drawn as reflection points (the
         bistatic ellipse of the delay met by the bearing ray, FORMATS.md frames) around the
         robot, and listed as text; its "pose", when the frame was tagged, moves the robot too.

`qwidget()` returns an embeddable QWidget (a matplotlib canvas and a text line) for GRC's
gui_hint; the block never opens a window of its own. The message handlers run in the
scheduler's threads: they parse each message into an immutable snapshot (under a lock) and
hand it to the GUI thread through a queued Qt signal; the widget redraws at most every
update_period_s. Without a widget (no GUI) the block still keeps the snapshot, for tests and
for scripts (`snapshot()`).

Qt and matplotlib are imported only when the widget is made, so importing the package needs
neither a display nor PyQt5.
"""

import math
import threading

import numpy as np
import pmt
from gnuradio import gr

from . import bistatic
from .survey_blocks import pose_from_pmt
from .wall_fusion import wall_style

PORT_MAP = pmt.intern("map")
PORT_POSE = pmt.intern("pose")
PORT_PATHS = pmt.intern("paths")
CLASSES = ("line_of_sight", "hidden")
COLOURS = {"line_of_sight": "tab:blue", "hidden": "tab:orange"}


class LiveMapError(ValueError):
    """A message the live map cannot read (the text names what is wrong)."""


def _f64(value, name):
    if pmt.is_f64vector(value):
        return np.asarray(pmt.f64vector_elements(value), float)
    if pmt.is_vector(value) or pmt.is_tuple(value):
        n = pmt.length(value)
        ref = pmt.vector_ref if pmt.is_vector(value) else pmt.tuple_ref
        items = [ref(value, i) for i in range(n)]
        if all(pmt.is_number(v) for v in items):
            return np.array([pmt.to_double(v) for v in items], float)
    raise LiveMapError(f"map message: {name} is not an f64vector")


def _get(d, key, default=None):
    k = pmt.intern(key)
    return pmt.dict_ref(d, k, pmt.PMT_NIL) if pmt.dict_has_key(d, k) else default


def map_from_pmt(msg):
    """wall_fusion's map message as plain Python: {"walls": [(cls, confidence, start (2,),
    end (2,), source)], "corners": [(position (2,), confidence)], "openings": [(start (2,),
    end (2,))], "detections": {cls: (n, 2)},
    "trajectory": (n, 3), "num_poses": int}. Raises LiveMapError naming the bad entry."""
    if not pmt.is_dict(msg):
        raise LiveMapError("map message: expected a dict (wall_fusion's \"map\" port)")
    walls = []
    vec = _get(msg, "walls")
    if vec is not None:
        if not pmt.is_vector(vec):
            raise LiveMapError("map message: walls is not a vector of dicts")
        for i in range(pmt.length(vec)):
            w = pmt.vector_ref(vec, i)
            if not pmt.is_dict(w):
                raise LiveMapError(f"map message: walls[{i}] is not a dict")
            cls = _get(w, "class")
            cls = pmt.symbol_to_string(cls) if cls is not None and pmt.is_symbol(cls) else "line_of_sight"
            conf = _get(w, "confidence")
            conf = pmt.to_double(conf) if conf is not None and pmt.is_number(conf) else 1.0
            start, end = _get(w, "start"), _get(w, "end")
            if start is None or end is None:
                raise LiveMapError(f"map message: walls[{i}] needs start and end")
            start, end = _f64(start, f"walls[{i}].start"), _f64(end, f"walls[{i}].end")
            if start.shape != (2,) or end.shape != (2,) or not np.all(np.isfinite(np.r_[start, end])):
                raise LiveMapError(f"map message: walls[{i}] start/end must be finite [x, y]")
            source = _get(w, "source")  # how it was found: echoes, end_wall, side_wall, inferred
            source = pmt.symbol_to_string(source) if source is not None and pmt.is_symbol(source) else "echoes"
            walls.append((cls, float(np.clip(conf, 0.0, 1.0)), start, end, source))
    corners = []
    vec = _get(msg, "corners")
    if vec is not None and pmt.is_vector(vec):
        for i in range(pmt.length(vec)):
            c = pmt.vector_ref(vec, i)
            if pmt.is_dict(c) and _get(c, "position") is not None:
                p = _f64(_get(c, "position"), f"corners[{i}].position")
                conf = _get(c, "confidence")
                if p.shape == (2,) and np.all(np.isfinite(p)):
                    corners.append((p, pmt.to_double(conf) if conf is not None and pmt.is_number(conf) else 1.0))
    openings = []  # open doorways: (start (2,), end (2,)); a message without them has none
    vec = _get(msg, "openings")
    if vec is not None:  # checked as the walls are: wall_fusion writes them, a bad one is an error
        if not pmt.is_vector(vec):
            raise LiveMapError("map message: openings is not a vector of dicts")
        for i in range(pmt.length(vec)):
            o = pmt.vector_ref(vec, i)
            if not pmt.is_dict(o) or _get(o, "start") is None or _get(o, "end") is None:
                raise LiveMapError(f"map message: openings[{i}] needs start and end")
            start, end = _f64(_get(o, "start"), f"openings[{i}].start"), _f64(_get(o, "end"), f"openings[{i}].end")
            if start.shape != (2,) or end.shape != (2,) or not np.all(np.isfinite(np.r_[start, end])):
                raise LiveMapError(f"map message: openings[{i}] start/end must be finite [x, y]")
            openings.append((start, end))
    detections = {}
    det = _get(msg, "detections")
    if det is not None and pmt.is_dict(det):
        for cls in CLASSES:
            v = _get(det, cls)
            if v is not None:
                xy = _f64(v, f"detections.{cls}")
                detections[cls] = xy[: len(xy) // 2 * 2].reshape(-1, 2)
    trajectory = np.zeros((0, 3))
    t = _get(msg, "trajectory")
    if t is not None:
        t = _f64(t, "trajectory")
        if len(t) % 3:
            raise LiveMapError("map message: trajectory must hold x, y, heading per pose")
        trajectory = t.reshape(-1, 3)
    n = _get(msg, "num_poses")
    num_poses = int(pmt.to_long(n)) if n is not None and pmt.is_integer(n) else len(trajectory)
    return {"walls": walls, "corners": corners, "openings": openings, "detections": detections,
            "trajectory": trajectory, "num_poses": num_poses}


def paths_from_pmt(msg):
    """(frame_index or None, pose (3,) or None, [{"angle_deg", "delay_s", "power", "stage"}])
    from a jade_estimator "paths" message. Raises LiveMapError."""
    if not pmt.is_dict(msg):
        raise LiveMapError("paths message: expected a dict (jade_estimator's \"paths\" port)")
    frame_index = None
    v = _get(msg, "frame_index")
    if v is not None and pmt.is_uint64(v):
        frame_index = int(pmt.to_uint64(v))
    elif v is not None and pmt.is_integer(v):
        frame_index = int(pmt.to_long(v))
    pose = None
    v = _get(msg, "pose")
    if v is not None:
        pose = pose_from_pmt(v)
    vec = _get(msg, "paths")
    if vec is None or not pmt.is_vector(vec):
        raise LiveMapError("paths message: no \"paths\" vector")
    paths = []
    for i in range(pmt.length(vec)):
        item = pmt.vector_ref(vec, i)
        if not pmt.is_dict(item):
            raise LiveMapError(f"paths message: paths[{i}] is not a dict")
        entry = {}
        for key in ("angle_deg", "delay_s", "power"):
            x = _get(item, key)
            entry[key] = pmt.to_double(x) if x is not None and pmt.is_number(x) else float("nan")
        s = _get(item, "stage")
        entry["stage"] = int(pmt.to_long(s)) if s is not None and pmt.is_integer(s) else 1
        paths.append(entry)
    return frame_index, pose, paths


def _radar_centres(radar):
    """TX and RX array centres (robot frame) of a radar_description, or of the default UCA pair."""
    if radar is None:
        return np.array([-0.35, 0.0]), np.array([0.35, 0.0])

    def value(name):
        v = getattr(radar, name)
        return v() if callable(v) else v

    tx = np.asarray(value("tx_elements_m"), float).reshape(-1, 2).mean(axis=0)
    rx = np.asarray(value("rx_elements_m"), float).reshape(-1, 2).mean(axis=0)
    return tx, rx


class live_map(gr.basic_block):
    """A live QT map of walls, corners, the trajectory, the robot and its latest echoes.

    radar: a thrumapper.radar_description (its array centres place the echoes; None: the
    ThruMapper UCA pair, centres at x = ∓0.35 m). title: the plot's title. update_period_s:
    the least time between two redraws. max_trail: poses kept in the trail drawn between map
    updates. show_echoes: draw the latest paths message's reflection points.
    """

    def __init__(self, radar=None, title="thrumapper live map", update_period_s=0.25, max_trail=5000,
                 show_echoes=True):
        gr.basic_block.__init__(self, name="live_map", in_sig=None, out_sig=None)
        if not (float(update_period_s) > 0):
            raise ValueError(f"update_period_s: expected > 0, got {update_period_s}")
        if int(max_trail) < 2:
            raise ValueError(f"max_trail: expected at least 2, got {max_trail}")
        self._tx_centre, self._rx_centre = _radar_centres(radar)
        self._title = str(title)
        self._update_period_s = float(update_period_s)
        self._max_trail = int(max_trail)
        self._show_echoes = bool(show_echoes)
        self._lock = threading.Lock()
        self._trail = []
        self._map = None
        self._pose = None
        self._echoes = np.zeros((0, 2))
        self._paths = []
        self._frame_index = None
        self._counts = {"maps": 0, "poses": 0, "paths": 0, "malformed": 0}
        self._snapshot = self._make_snapshot()
        self._widget = None
        self._warnings = 0
        for port, handler in ((PORT_MAP, self._on_map), (PORT_POSE, self._on_pose), (PORT_PATHS, self._on_paths)):
            self.message_port_register_in(port)
            self.set_msg_handler(port, handler)

    # -- messages (scheduler threads) --------------------------------------------------------
    def _warn(self, text):
        self._warnings += 1
        if self._warnings <= 10 or self._warnings % 1000 == 0:
            self.logger.warn(f"live_map: {text} ({self._warnings} warnings so far)")

    def _add_pose(self, pose):
        self._pose = pose
        if not self._trail or np.hypot(*(self._trail[-1][:2] - pose[:2])) > 1e-3:
            self._trail.append(pose)
            del self._trail[:-self._max_trail]

    def _parsed(self, parse, msg):
        """parse(msg), or None once a malformed message is counted and logged."""
        try:
            return parse(msg)
        except LiveMapError as err:
            with self._lock:
                self._counts["malformed"] += 1
            self._warn(f"{err}; skipped")
            return None

    def _on_map(self, msg):
        parsed = self._parsed(map_from_pmt, msg)
        if parsed is None:
            return
        with self._lock:
            self._map = parsed
            self._counts["maps"] += 1
            if self._pose is None and len(parsed["trajectory"]):
                self._pose = parsed["trajectory"][-1]
        self._publish()

    def _on_pose(self, msg):
        pose = pose_from_pmt(msg)
        with self._lock:
            if pose is None:
                self._counts["malformed"] += 1
            else:
                self._counts["poses"] += 1
                self._add_pose(pose)
        if pose is None:
            self._warn("a pose message without a finite [x, y, heading]; skipped")
            return
        self._publish()

    def _on_paths(self, msg):
        parsed = self._parsed(paths_from_pmt, msg)
        if parsed is None:
            return
        frame_index, pose, paths = parsed
        with self._lock:
            self._counts["paths"] += 1
            self._frame_index = frame_index
            self._paths = paths
            if pose is not None:
                self._add_pose(pose)
            self._echoes = self._echo_points(paths, self._pose)
        self._publish()

    def _echo_points(self, paths, pose):
        """World reflection points of the paths seen from pose ((0, 2) without a pose)."""
        if pose is None or not paths:
            return np.zeros((0, 2))
        points = []
        for p in paths:
            try:
                point, _ = bistatic.reflection_point(math.radians(p["angle_deg"]), p["delay_s"],
                                                     self._tx_centre, self._rx_centre)
            except (bistatic.GeometryError, ValueError):
                continue  # earlier than the direct path, NaN: no reflector
            points.append(point)
        if not points:
            return np.zeros((0, 2))
        return np.asarray(bistatic.robot_to_world(np.asarray(points), pose), float).reshape(-1, 2)

    def _make_snapshot(self):
        """An immutable view of the state for the GUI thread (called with the lock held)."""
        return {
            "map": self._map,
            "trail": np.array(self._trail, float).reshape(-1, 3),
            "pose": None if self._pose is None else np.array(self._pose, float),
            "echoes": np.array(self._echoes, float).reshape(-1, 2),
            "paths": [dict(p) for p in self._paths],
            "frame_index": self._frame_index,
            "counts": dict(self._counts),
        }

    def _publish(self):
        with self._lock:
            snapshot = self._snapshot = self._make_snapshot()
            widget = self._widget
        if widget is not None:
            widget.post(snapshot)  # a queued Qt signal: the GUI thread draws it

    # -- the GUI -------------------------------------------------------------------------------
    def qwidget(self):
        """The QWidget to embed (made on the first call, in the GUI thread, which needs a
        QApplication); GRC's gui_hint places it."""
        with self._lock:
            widget = self._widget
        if widget is None:
            widget = _widget_class()(self._title, self._update_period_s, self._show_echoes)
            with self._lock:
                self._widget = widget
                snapshot = self._snapshot
            widget.post(snapshot)
        return widget

    def set_update_period(self, update_period_s):
        if not (float(update_period_s) > 0):
            raise ValueError(f"update_period_s: expected > 0, got {update_period_s}")
        with self._lock:
            self._update_period_s = float(update_period_s)
            widget = self._widget
        if widget is not None:
            widget.set_update_period(self._update_period_s)

    def set_title(self, title):
        with self._lock:
            self._title = str(title)
            widget = self._widget
        if widget is not None:
            widget.set_title(self._title)

    # -- accessors -----------------------------------------------------------------------------
    def snapshot(self):
        """The latest state: map (map_from_pmt's dict or None), trail (n, 3), pose, echoes
        (n, 2) world points, paths, frame_index, counts."""
        with self._lock:
            return self._snapshot

    def counts(self):
        """Messages taken, by port, and malformed ones skipped."""
        with self._lock:
            return dict(self._counts)


_WIDGET_CLASS = None


def _widget_class():
    """The QWidget class, made on first use so that importing this module needs no Qt."""
    global _WIDGET_CLASS
    if _WIDGET_CLASS is not None:
        return _WIDGET_CLASS
    from PyQt5 import QtCore, QtWidgets
    from matplotlib.backends.backend_qt5agg import FigureCanvasQTAgg
    from matplotlib.figure import Figure

    class LiveMapWidget(QtWidgets.QWidget):
        """The map canvas and a status line; post(), set_update_period() and set_title() may be
        called from any thread (they emit queued signals)."""

        snapshot_ready = QtCore.pyqtSignal(object)
        period_changed = QtCore.pyqtSignal(int)
        title_changed = QtCore.pyqtSignal(str)

        def __init__(self, title, update_period_s, show_echoes, parent=None):
            super().__init__(parent)
            self._title = title
            self._show_echoes = show_echoes
            self._snapshot = None
            self._dirty = False
            self.redraws = 0
            self.figure = Figure(figsize=(6.0, 4.0), dpi=90)
            self.canvas = FigureCanvasQTAgg(self.figure)
            self.canvas.setSizePolicy(QtWidgets.QSizePolicy.Expanding, QtWidgets.QSizePolicy.Expanding)
            # never a degenerate canvas: matplotlib's equal aspect divides by its size
            self.canvas.setMinimumSize(240, 180)
            self.axes = self.figure.add_subplot(111)
            self.status = QtWidgets.QLabel("waiting for the map")
            self.status.setWordWrap(True)
            self.status.setTextInteractionFlags(QtCore.Qt.TextSelectableByMouse)
            layout = QtWidgets.QVBoxLayout(self)
            layout.setContentsMargins(0, 0, 0, 0)
            layout.addWidget(self.canvas, 1)
            layout.addWidget(self.status, 0)
            # Emitted from the scheduler's threads; the receiver lives in the GUI thread, so Qt
            # queues the call there (the snapshot is immutable: nothing is shared).
            self.snapshot_ready.connect(self._on_snapshot, QtCore.Qt.QueuedConnection)
            self._timer = QtCore.QTimer(self)
            self._timer.timeout.connect(self._redraw_if_dirty)
            self.period_changed.connect(self._timer.start, QtCore.Qt.QueuedConnection)
            self.title_changed.connect(self._on_title, QtCore.Qt.QueuedConnection)
            self._timer.start(max(20, int(round(update_period_s * 1000))))
            self._draw_empty()

        def post(self, snapshot):
            self.snapshot_ready.emit(snapshot)

        def set_update_period(self, update_period_s):
            self.period_changed.emit(max(20, int(round(update_period_s * 1000))))

        def set_title(self, title):
            self.title_changed.emit(str(title))

        def _on_title(self, title):
            self._title = title
            self._dirty = True

        def _on_snapshot(self, snapshot):
            self._snapshot = snapshot
            self._dirty = True

        def _drawable(self):
            # matplotlib's equal aspect divides by the canvas size: not before it has one
            return self.isVisible() and self.canvas.width() > 20 and self.canvas.height() > 20

        def _redraw_if_dirty(self):
            if self._dirty and self._drawable():
                self._dirty = False
                self.redraw()

        def _draw_empty(self):
            ax = self.axes
            ax.clear()
            ax.set_title(self._title, fontsize=10)
            ax.set_xlabel("x (m, world)")
            ax.set_ylabel("y (m, world)")
            ax.grid(True, lw=0.3)
            ax.set_aspect("equal", adjustable="datalim")
            if self._drawable():
                self.canvas.draw_idle()

        def _set_limits(self, snap):
            """Limits around everything drawn, at least 3 m across: one pose or one straight
            wall alone would give the equal-aspect axes a zero span."""
            points = [np.zeros((0, 2))]
            m = snap["map"]
            if m is not None:
                points += [np.array([start, end]) for _, _, start, end, _ in m["walls"]]
                points += [np.array([p]) for p, _ in m["corners"]]
                points += [d for d in m["detections"].values()]
                points.append(m["trajectory"][:, :2])
            points += [snap["trail"][:, :2], snap["echoes"]]
            if snap["pose"] is not None:
                points.append(snap["pose"][None, :2])
            xy = np.vstack([np.asarray(p, float).reshape(-1, 2) for p in points])
            xy = xy[np.all(np.isfinite(xy), axis=1)]
            if not len(xy):
                return
            low, high = xy.min(axis=0), xy.max(axis=0)
            centre, span = (low + high) / 2, max(3.0, float(np.max(high - low)) * 1.1 + 0.5)
            self.axes.set_xlim(centre[0] - span / 2, centre[0] + span / 2)
            self.axes.set_ylim(centre[1] - span / 2, centre[1] + span / 2)

        def redraw(self):
            snap = self._snapshot
            if snap is None:
                return
            self._draw_empty()
            ax = self.axes
            m = snap["map"]  # (redraw is only called when _drawable)
            if m is not None:
                labelled = set()
                for cls, conf, start, end, source in m["walls"]:
                    style, found_by = wall_style(source)  # as in the PNG
                    label = None if (cls, found_by) in labelled else f"wall, {cls.replace('_', ' ')}{found_by}"
                    labelled.add((cls, found_by))
                    ax.plot([start[0], end[0]], [start[1], end[1]], style, color=COLOURS.get(cls, "tab:green"),
                            lw=1.0 + 2.5 * conf, label=label, solid_capstyle="butt")
                for cls in CLASSES:
                    d = m["detections"].get(cls)
                    if d is not None and len(d):
                        ax.plot(d[:, 0], d[:, 1], "x", ms=3, color=COLOURS[cls], alpha=0.6)
                for i, (p, _) in enumerate(m["corners"]):
                    ax.plot(p[0], p[1], "s", ms=8, mfc="none", mec="tab:red", mew=2,
                            label="corner" if i == 0 else None)
                for i, (start, end) in enumerate(m.get("openings", ())):  # as in the PNG
                    ax.plot([start[0], end[0]], [start[1], end[1]], ":", color="tab:green", lw=1.5, marker="|",
                            ms=10, mew=2, label="open doorway" if i == 0 else None)
                t = m["trajectory"]
                if len(t):
                    ax.plot(t[:, 0], t[:, 1], "-", color="k", lw=1.2, label="trajectory (fusion)")
            trail = snap["trail"]
            if len(trail) > 1:
                ax.plot(trail[:, 0], trail[:, 1], ":", color="0.4", lw=1.0, label="poses")
            pose = snap["pose"]
            if self._show_echoes and len(snap["echoes"]):
                e = snap["echoes"]
                ax.plot(e[:, 0], e[:, 1], "o", ms=5, mfc="none", mec="tab:purple", label="latest echoes")
                if pose is not None:
                    for x, y in e:
                        ax.plot([pose[0], x], [pose[1], y], "-", color="tab:purple", lw=0.4, alpha=0.5)
            if pose is not None:
                ax.plot(pose[0], pose[1], "o", ms=7, color="tab:green", label="robot")
                ax.annotate("", xy=(pose[0] + 0.4 * math.cos(pose[2]), pose[1] + 0.4 * math.sin(pose[2])),
                            xytext=(pose[0], pose[1]), arrowprops={"arrowstyle": "->", "color": "tab:green"})
            self._set_limits(snap)
            if ax.get_legend_handles_labels()[0]:
                ax.legend(loc="upper right", fontsize=7, framealpha=0.7)
            self.canvas.draw_idle()
            self.status.setText(_status_text(snap))
            self.redraws += 1

    _WIDGET_CLASS = LiveMapWidget
    return _WIDGET_CLASS


def _status_text(snap):
    parts = []
    m = snap["map"]
    if m is not None:
        walls = m["walls"]
        n_hidden = sum(1 for w in walls if w[0] == "hidden")
        parts.append(f"map: {m['num_poses']} poses, {len(walls) - n_hidden} line-of-sight and {n_hidden} hidden "
                     f"walls, {len(m['corners'])} corners")
    pose = snap["pose"]
    if pose is not None:
        parts.append(f"robot ({pose[0]:.2f}, {pose[1]:.2f}) m, {math.degrees(pose[2]):.1f}°")
    if snap["paths"]:
        head = f"frame {snap['frame_index']}: " if snap["frame_index"] is not None else ""
        items = []
        for p in snap["paths"][:6]:
            power_db = 10 * math.log10(p["power"]) if p["power"] > 0 else float("nan")
            items.append(f"{p['angle_deg']:.1f}° {p['delay_s'] * 1e9:.2f} ns {power_db:.0f} dB (stage {p['stage']})")
        parts.append(head + "; ".join(items))
    return " · ".join(parts) if parts else "waiting for the map"
