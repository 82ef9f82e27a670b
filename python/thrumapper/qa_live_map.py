#!/usr/bin/env python3
#
# SPDX-License-Identifier: GPL-3.0-or-later
#
"""live_map: messages in (posted, polled with a deadline), the snapshot and the QT widget
(offscreen: no display needed)."""

import os

os.environ.setdefault("QT_QPA_PLATFORM", "offscreen")

import math  # noqa: E402
import time  # noqa: E402
import unittest  # noqa: E402

import numpy as np  # noqa: E402
import pmt  # noqa: E402
from gnuradio import blocks, gr, gr_unittest  # noqa: E402
from gnuradio import thrumapper  # noqa: E402
from gnuradio.thrumapper.live_map import live_map, map_from_pmt, LiveMapError  # noqa: E402
from gnuradio.thrumapper.testing import free_finished_flowgraphs  # noqa: E402


def f64(values):
    values = [float(v) for v in values]
    return pmt.init_f64vector(len(values), values)


def wall(cls, confidence, start, end):
    d = pmt.make_dict()
    d = pmt.dict_add(d, pmt.intern("class"), pmt.intern(cls))
    d = pmt.dict_add(d, pmt.intern("confidence"), pmt.from_double(confidence))
    d = pmt.dict_add(d, pmt.intern("start"), f64(start))
    d = pmt.dict_add(d, pmt.intern("end"), f64(end))
    return pmt.dict_add(d, pmt.intern("num_poses"), pmt.from_long(12))


def map_message():
    """A map as wall_fusion publishes it: a corridor wall 0.7 m to the right, a hidden wall
    1.65 m behind it, a corner, an open doorway, detections and three poses."""
    walls = pmt.make_vector(2, pmt.PMT_NIL)
    pmt.vector_set(walls, 0, wall("line_of_sight", 0.9, [0.0, -0.7], [5.0, -0.7]))
    pmt.vector_set(walls, 1, pmt.dict_add(wall("hidden", 0.5, [0.0, -2.35], [4.0, -2.35]), pmt.intern("source"),
                                          pmt.intern("inferred")))
    corners = pmt.make_vector(1, pmt.PMT_NIL)
    c = pmt.dict_add(pmt.make_dict(), pmt.intern("position"), f64([6.5, -0.7]))
    c = pmt.dict_add(c, pmt.intern("confidence"), pmt.from_double(0.8))
    pmt.vector_set(corners, 0, c)
    openings = pmt.make_vector(1, pmt.PMT_NIL)  # a doorway in the corridor wall, past its end
    o = pmt.dict_add(pmt.make_dict(), pmt.intern("start"), f64([5.0, -0.7]))
    o = pmt.dict_add(o, pmt.intern("end"), f64([5.9, -0.7]))
    pmt.vector_set(openings, 0, pmt.dict_add(o, pmt.intern("confidence"), pmt.from_double(0.8)))
    det = pmt.dict_add(pmt.make_dict(), pmt.intern("line_of_sight"), f64([1.0, -0.7, 2.0, -0.7]))
    det = pmt.dict_add(det, pmt.intern("hidden"), f64([1.0, -2.35]))
    msg = pmt.make_dict()
    msg = pmt.dict_add(msg, pmt.intern("num_poses"), pmt.from_long(3))
    msg = pmt.dict_add(msg, pmt.intern("walls"), walls)
    msg = pmt.dict_add(msg, pmt.intern("corners"), corners)
    msg = pmt.dict_add(msg, pmt.intern("openings"), openings)
    msg = pmt.dict_add(msg, pmt.intern("detections"), det)
    return pmt.dict_add(msg, pmt.intern("trajectory"), f64([0, 0, 0, 0.2, 0, 0, 0.4, 0, 0]))


def paths_message(pose, paths, frame_index=7):
    """jade_estimator's message: paths as (angle_deg, delay_s, power, stage)."""
    vec = pmt.make_vector(len(paths), pmt.PMT_NIL)
    for i, (angle, delay, power, stage) in enumerate(paths):
        d = pmt.make_dict()
        d = pmt.dict_add(d, pmt.intern("angle_deg"), pmt.from_double(angle))
        d = pmt.dict_add(d, pmt.intern("delay_s"), pmt.from_double(delay))
        d = pmt.dict_add(d, pmt.intern("power"), pmt.from_double(power))
        d = pmt.dict_add(d, pmt.intern("spectrum_db"), pmt.from_double(20.0))
        d = pmt.dict_add(d, pmt.intern("stage"), pmt.from_long(stage))
        pmt.vector_set(vec, i, d)
    msg = pmt.dict_add(pmt.make_dict(), pmt.intern("frame_index"), pmt.from_uint64(frame_index))
    msg = pmt.dict_add(msg, pmt.intern("model_order"), pmt.from_long(len(paths)))
    if pose is not None:
        msg = pmt.dict_add(msg, pmt.intern("pose"), f64(pose))
    return pmt.dict_add(msg, pmt.intern("paths"), vec)


def wait_for(predicate, timeout_s=10.0, app=None):
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if app is not None:
            app.processEvents()
        if predicate():
            return True
        time.sleep(0.01)
    return predicate()


class qa_live_map(gr_unittest.TestCase):
    def setUp(self):
        self.tb = gr.top_block()
        self.radar = thrumapper.radar_description.make_uca_pair()
        self.live = live_map(self.radar, "test map", 0.05)
        # a message-only block joins a flowgraph through a connection: an odometry stand-in
        # (its first message comes after 1 s; the tests post theirs directly)
        self.odometry = blocks.message_strobe(pmt.to_pmt({"x": 9.0, "y": 9.0, "heading": 0.0}), 1000)
        self.tb.msg_connect((self.odometry, "strobe"), (self.live, "pose"))

    def tearDown(self):
        self.tb.stop()
        self.tb.wait()
        self.tb = None
        free_finished_flowgraphs()

    def test_worked_example_echo_position(self):
        """The yml's worked example: robot at [2, 0, 0], a path at 243.43°, 5.221 ns → the
        reflection point (2.00, -0.70) in the world."""
        self.tb.start()
        delay = 2 * math.hypot(0.7, 0.35) / 299792458.0
        angle = 270 - math.degrees(math.atan(0.35 / 0.7))
        self.live._post(pmt.intern("paths"), paths_message([2.0, 0.0, 0.0], [(angle, delay, 1e-6, 1)]))
        self.assertTrue(wait_for(lambda: self.live.counts()["paths"] == 1))
        snap = self.live.snapshot()
        self.assertEqual(snap["echoes"].shape, (1, 2))
        np.testing.assert_allclose(snap["echoes"][0], [2.0, -0.7], atol=1e-6)
        np.testing.assert_allclose(snap["pose"], [2.0, 0.0, 0.0])
        self.assertEqual(snap["frame_index"], 7)
        self.assertAlmostEqual(snap["paths"][0]["angle_deg"], angle)

    def test_echoes_follow_the_pose_and_skip_unphysical_delays(self):
        self.tb.start()
        delay = 2 * math.hypot(0.7, 0.35) / 299792458.0
        angle = 270 - math.degrees(math.atan(0.35 / 0.7))
        # heading 90°: the robot's right is world -x; a path earlier than the direct path
        # (2.335 ns) has no reflector and is left out of the points
        msg = paths_message([1.0, 1.0, math.pi / 2], [(angle, delay, 1e-6, 1), (30.0, 1.0e-9, 1e-7, 1)])
        self.live._post(pmt.intern("paths"), msg)
        self.assertTrue(wait_for(lambda: self.live.counts()["paths"] == 1))
        snap = self.live.snapshot()
        np.testing.assert_allclose(snap["echoes"], [[1.7, 1.0]], atol=1e-6)
        self.assertEqual(len(snap["paths"]), 2)

    def test_map_pose_and_malformed_messages(self):
        self.tb.start()
        self.live._post(pmt.intern("map"), map_message())
        self.live._post(pmt.intern("pose"), pmt.to_pmt({"pose": [0.5, 0.1, 0.0]}))  # not f64: vector of doubles
        pose = pmt.dict_add(pmt.make_dict(), pmt.intern("pose"), f64([0.6, 0.0, 0.1]))
        self.live._post(pmt.intern("pose"), pose)
        self.live._post(pmt.intern("map"), pmt.intern("garbage"))
        self.live._post(pmt.intern("paths"), pmt.from_long(3))
        self.assertTrue(wait_for(lambda: sum(self.live.counts().values()) == 5))
        counts = self.live.counts()
        self.assertEqual(counts["maps"], 1)
        self.assertEqual(counts["poses"], 1)
        self.assertEqual(counts["malformed"], 3)
        snap = self.live.snapshot()
        m = snap["map"]
        self.assertEqual([w[0] for w in m["walls"]], ["line_of_sight", "hidden"])
        # how each wall was found: the message's "source", "echoes" when it has none
        self.assertEqual([w[4] for w in m["walls"]], ["echoes", "inferred"])
        np.testing.assert_allclose(m["walls"][1][2], [0.0, -2.35])
        self.assertEqual(m["trajectory"].shape, (3, 3))
        np.testing.assert_allclose(m["detections"]["line_of_sight"], [[1.0, -0.7], [2.0, -0.7]])
        np.testing.assert_allclose(snap["pose"], [0.6, 0.0, 0.1])

    def test_map_from_pmt_names_the_bad_entry(self):
        bad = pmt.make_vector(1, pmt.PMT_NIL)
        pmt.vector_set(bad, 0, wall("hidden", 0.5, [0.0, float("nan")], [1.0, 0.0]))
        msg = pmt.dict_add(pmt.make_dict(), pmt.intern("walls"), bad)
        with self.assertRaisesRegex(LiveMapError, r"walls\[0\]"):
            map_from_pmt(msg)
        parsed = map_from_pmt(map_message())
        self.assertEqual(len(parsed["openings"]), 1)
        self.assertAlmostEqual(float(np.hypot(*(parsed["openings"][0][1] - parsed["openings"][0][0]))), 0.9)
        self.assertEqual(map_from_pmt(pmt.make_dict())["openings"], [])  # a message without them
        bad_opening = pmt.make_vector(1, pmt.PMT_NIL)
        o = pmt.dict_add(pmt.make_dict(), pmt.intern("start"), f64([0.0, float("nan")]))
        pmt.vector_set(bad_opening, 0, pmt.dict_add(o, pmt.intern("end"), f64([1.0, 0.0])))
        with self.assertRaisesRegex(LiveMapError, r"openings\[0\]"):
            map_from_pmt(pmt.dict_add(pmt.make_dict(), pmt.intern("openings"), bad_opening))
        with self.assertRaises(ValueError):
            live_map(update_period_s=0)

    def test_widget_draws_the_map_in_the_gui_thread(self):
        """Messages from the scheduler's threads reach the widget by a queued signal; it draws
        the walls by class and lists the paths."""
        from PyQt5 import QtWidgets

        app = QtWidgets.QApplication.instance() or QtWidgets.QApplication(["qa_live_map"])
        widget = self.live.qwidget()
        self.assertIs(widget, self.live.qwidget())  # one widget, embedded by gui_hint
        self.assertIsInstance(widget, QtWidgets.QWidget)
        self.assertIsNone(widget.parent())  # no window of its own: GRC's layout adopts it
        widget.resize(640, 480)
        widget.show()
        self.tb.start()
        self.live._post(pmt.intern("map"), map_message())
        delay = 2 * math.hypot(0.7, 0.35) / 299792458.0
        self.live._post(pmt.intern("paths"),
                        paths_message([0.4, 0.0, 0.0], [(243.43, delay, 1e-5, 1), (260.0, 15.2e-9, 1e-8, 2)]))
        self.assertTrue(wait_for(lambda: "line-of-sight" in widget.status.text() and "260.0°" in widget.status.text(),
                                 app=app))
        self.assertIn("1 line-of-sight and 1 hidden walls, 1 corners", widget.status.text())
        self.assertIn("stage 2", widget.status.text())
        colours = [line.get_color() for line in widget.axes.get_lines()]
        self.assertIn("tab:blue", colours)
        self.assertIn("tab:orange", colours)
        self.assertIn("tab:red", [line.get_markeredgecolor() for line in widget.axes.get_lines()])
        self.assertIn("open doorway", [line.get_label() for line in widget.axes.get_lines()])
        self.assertGreaterEqual(widget.redraws, 1)
        # the canvas really holds the blue corridor wall (#1f77b4)
        widget.canvas.draw()
        image = np.asarray(widget.canvas.buffer_rgba())[:, :, :3].astype(int)
        blue = np.sum((np.abs(image[:, :, 0] - 0x1f) < 30) & (np.abs(image[:, :, 1] - 0x77) < 30)
                      & (np.abs(image[:, :, 2] - 0xb4) < 30))
        self.assertGreater(blue, 200)
        widget.close()


if __name__ == "__main__":
    gr_unittest.run(qa_live_map)
