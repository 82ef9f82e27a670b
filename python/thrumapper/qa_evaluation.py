#!/usr/bin/env python3
#
# SPDX-License-Identifier: GPL-3.0-or-later
#
"""Tests of map scoring against hand-computed distances, lengths and counts."""

import contextlib
import copy
import importlib.util
import io
import json
import math
import os
import sys
import tempfile

import numpy as np
from gnuradio import gr_unittest

try:
    from gnuradio.thrumapper import cli_eval, evaluation
except ImportError:
    # Not installed (or the C++ extension is not built): import the sibling files as a package.
    _here = os.path.dirname(os.path.abspath(__file__))
    _spec = importlib.util.spec_from_file_location("thrumapper_local", os.path.join(_here, "__init__.py"),
                                                   submodule_search_locations=[_here])
    _package = importlib.util.module_from_spec(_spec)
    sys.modules["thrumapper_local"] = _package
    _spec.loader.exec_module(_package)
    from thrumapper_local import cli_eval, evaluation


def _feature(geometry_type, coordinates, **properties):
    return {"type": "Feature", "geometry": {"type": geometry_type, "coordinates": coordinates},
            "properties": properties}


def _cli(*args):
    """thrumapper-eval run with args: (exit status, stdout, stderr)."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        status = cli_eval.main(list(args))
    return status, out.getvalue(), err.getvalue()


def _collection(features):
    return {"type": "FeatureCollection", "thrumapper:crs": "local-metres", "features": features}


def _truth():
    """A 10 m line-of-sight face at y = -1 and a hidden one at y = -3; two corners; 10 poses."""
    return _collection([
        _feature("LineString", [[0, -1], [10, -1]], kind="wall", **{"class": "line_of_sight"}, confidence=1.0),
        _feature("LineString", [[0, -3], [10, -3]], kind="wall", **{"class": "hidden"}, confidence=1.0),
        _feature("Point", [10, -1], kind="corner", confidence=1.0),
        _feature("Point", [10, -3], kind="corner", confidence=1.0),
        _feature("LineString", [[float(x), 0.0] for x in range(10)], kind="trajectory"),
    ])


def _map():
    los_points = [[x + 0.5, -1.1] for x in range(10)]  # 0.1 m off the LoS face
    hidden_points = [[x + 0.5, -3.2 if x % 2 else -2.8] for x in range(10)]  # 0.2 m off, both sides
    return _collection([
        _feature("MultiPoint", los_points, kind="detections", **{"class": "line_of_sight"}),
        _feature("MultiPoint", hidden_points, kind="detections", **{"class": "hidden"}),
        # Half the LoS face, 0.1 m off: covers x ∈ [0, 5 + √(0.3² − 0.1²)].
        _feature("LineString", [[0, -1.1], [5, -1.1]], kind="wall", **{"class": "line_of_sight"}, confidence=0.9),
        # A wall 2 m from any true one: 3 m of false wall.
        _feature("LineString", [[0, 1.0], [1.5, 1.0], [3, 1.0]], kind="wall", **{"class": "line_of_sight"},
                 confidence=0.4),
        # 0.4 m off the hidden face: too far to cover it (0.3 m), too near to be false (0.5 m).
        _feature("LineString", [[2, -3.4], [8, -3.4]], kind="wall", **{"class": "hidden"}, confidence=0.5),
        _feature("Point", [10.3, -1.2], kind="corner", confidence=0.8),  # 0.36 m from a true corner
        _feature("Point", [5.0, 5.0], kind="corner", confidence=0.3),  # near none
        _feature("LineString", [[x + 0.05, 0.0] for x in range(10)], kind="trajectory"),
        _feature("Point", [1.0, 2.0], kind="label", text="ignored: a kind the reader does not know"),
    ])


class qa_evaluation(gr_unittest.TestCase):
    def _list_option(self, map_path, truth_path, option, one_has, one_lacks, none_lacks):
        """A list below thrumapper-eval's table (--missed, --sources): with 1 it holds
        one_has and not one_lacks (the second entry), with 0 it is gone, -1 is refused."""
        status, out, _ = _cli(map_path, truth_path, option, "1")
        self.assertEqual(status, 0)
        for text in one_has:
            self.assertIn(text, out)
        self.assertNotIn(one_lacks, out)
        status, out, _ = _cli(map_path, truth_path, option, "0")
        self.assertEqual(status, 0)
        self.assertNotIn(none_lacks, out)
        status, _, err = _cli(map_path, truth_path, option, "-1")
        self.assertEqual(status, 2)
        self.assertIn(f"{option} must be >= 0", err)

    def test_scores_match_hand_computation(self):
        scores = evaluation.score_map(_map(), _truth())
        los, hidden = scores["classes"]["line_of_sight"], scores["classes"]["hidden"]
        self.assertEqual(los["detections"]["count"], 10)
        self.assertAlmostEqual(los["detections"]["rms_m"], 0.1, delta=1e-12)
        self.assertAlmostEqual(los["detections"]["median_m"], 0.1, delta=1e-12)
        self.assertAlmostEqual(hidden["detections"]["rms_m"], 0.2, delta=1e-12)
        self.assertAlmostEqual(hidden["detections"]["median_m"], 0.2, delta=1e-12)
        self.assertAlmostEqual(los["truth_wall_length_m"], 10.0, delta=1e-9)
        covered = 5.0 + math.sqrt(0.3**2 - 0.1**2)
        self.assertAlmostEqual(los["covered_length_m"], covered, delta=0.011)  # 1 cm sampling
        self.assertAlmostEqual(los["coverage"], covered / 10.0, delta=0.0011)
        self.assertEqual(hidden["covered_length_m"], 0.0)
        self.assertAlmostEqual(los["map_wall_length_m"], 8.0, delta=1e-9)
        self.assertAlmostEqual(los["false_wall_length_m"], 3.0, delta=1e-9)
        self.assertEqual(hidden["false_wall_length_m"], 0.0)
        self.assertAlmostEqual(scores["false_wall_length_m"], 3.0, delta=1e-9)
        self.assertEqual(scores["corners"]["truth"], 2)
        self.assertEqual(scores["corners"]["found"], 1)
        self.assertEqual(scores["corners"]["unmatched_map"], 1)
        self.assertAlmostEqual(scores["corners"]["fraction"], 0.5)
        self.assertTrue(scores["trajectory"]["pointwise"])
        self.assertAlmostEqual(scores["trajectory"]["rms_m"], 0.05, delta=1e-12)
        json.dumps(scores, allow_nan=False)  # plain JSON, no NaN

    def test_false_wall_partly_near_truth(self):
        # A map wall from y = -1 straight away from the face: its first 0.5 m is near the truth.
        truth = _truth()
        map_data = _collection([_feature("LineString", [[5, -1], [5, 1]], kind="wall",
                                         **{"class": "line_of_sight"}, confidence=1.0)])
        scores = evaluation.score_map(map_data, truth)
        self.assertAlmostEqual(scores["classes"]["line_of_sight"]["false_wall_length_m"], 1.5, delta=0.011)
        # It crosses the LoS face at one point: it covers ±0.3 m of it.
        self.assertAlmostEqual(scores["classes"]["line_of_sight"]["covered_length_m"], 0.6, delta=0.021)

    def test_trajectory_of_other_length(self):
        map_data = _collection([_feature("LineString", [[0.5, 0.2], [4.5, 0.2], [8.5, 0.2]], kind="trajectory")])
        scores = evaluation.score_map(map_data, _truth())
        self.assertFalse(scores["trajectory"]["pointwise"])
        self.assertAlmostEqual(scores["trajectory"]["rms_m"], 0.2, delta=1e-12)

    def test_open_doorways_scored(self):
        """Two true open doorways on the face y = -1 (x = 2-3 and 6-7.2); the map has one
        0.1 m along and 0.05 m off the first (its jambs 0.1 m and 0.1 m off, drawn the other
        way round), and one at x = 9 where no door is: 1 of 2 found, 1 false, jamb error
        RMS sqrt(0.1^2 + 0.05^2) m. Within 0.05 m of tolerance the found one is missed; the
        table names them; a malformed opening is refused by its index."""
        truth = _truth()
        truth["features"] += [_feature("LineString", [[2, -1], [3, -1]], kind="opening", confidence=1.0),
                              _feature("LineString", [[6, -1], [7.2, -1]], kind="opening", confidence=1.0)]
        ours = _collection([_feature("LineString", [[3.1, -1.05], [2.1, -1.05]], kind="opening", confidence=0.8),
                            _feature("LineString", [[8.6, -1.0], [9.4, -1.0]], kind="opening", confidence=0.5)])
        openings = evaluation.score_map(ours, truth)["openings"]
        self.assertEqual((openings["truth"], openings["map"], openings["found"], openings["unmatched_map"]), (2, 2, 1, 1))
        self.assertAlmostEqual(openings["fraction"], 0.5)
        self.assertAlmostEqual(openings["jamb_error_rms_m"], math.hypot(0.1, 0.05), places=9)
        self.assertEqual(evaluation.score_map(ours, truth, opening_tolerance_m=0.05)["openings"]["found"], 0)
        self.assertIn("open doorways found within 0.5 m: 1 of 2", evaluation.format_table(evaluation.score_map(ours, truth)))
        none = evaluation.score_map(_map(), _truth())["openings"]
        self.assertEqual((none["truth"], none["map"], none["fraction"]), (0, 0, None))
        self.assertNotIn("open doorways", evaluation.format_table(evaluation.score_map(_map(), _truth())))
        bad = copy.deepcopy(ours)
        bad["features"][1]["geometry"]["coordinates"] = [[8.6, -1.0]]
        with self.assertRaises(evaluation.MapFormatError) as ctx:
            evaluation.load_map(bad, "map.geojson")
        self.assertIn("features[1] (kind 'opening').geometry.coordinates", str(ctx.exception))

    def test_empty_map(self):
        scores = evaluation.score_map(_collection([]), _truth())
        los = scores["classes"]["line_of_sight"]
        self.assertEqual(los["detections"]["count"], 0)
        self.assertIsNone(los["detections"]["rms_m"])
        self.assertEqual(los["coverage"], 0.0)
        self.assertIsNone(scores["trajectory"])
        self.assertIn("trajectory", evaluation.format_table(scores))

    def test_malformed_geojson_names_the_problem(self):
        def broken(change):
            data = copy.deepcopy(_map())
            change(data)
            return data

        cases = [
            (lambda d: d.pop("thrumapper:crs"), "thrumapper:crs"),
            (lambda d: d.update({"type": "Feature"}), "type"),
            (lambda d: d.update({"features": {}}), "features"),
            (lambda d: d["features"][2]["properties"].pop("class"), "features[2] (kind 'wall').properties.class"),
            (lambda d: d["features"][2]["properties"].update({"class": "LoS"}), "properties.class"),
            (lambda d: d["features"][2]["properties"].update({"confidence": 1.5}), "properties.confidence"),
            (lambda d: d["features"][2]["geometry"].update({"coordinates": [[0, 1]]}),
             "features[2] (kind 'wall').geometry.coordinates"),
            (lambda d: d["features"][3]["geometry"]["coordinates"][1].__setitem__(0, "x"),
             "features[3] (kind 'wall').geometry.coordinates[1]"),
            (lambda d: d["features"][0]["geometry"].update({"type": "LineString"}), "features[0] (kind 'detections')"
             ".geometry.type"),
            (lambda d: d["features"][5].pop("geometry"), "features[5] (kind 'corner').geometry"),
            (lambda d: d["features"].append(copy.deepcopy(d["features"][7])), "second trajectory"),
        ]
        for change, expected in cases:
            with self.assertRaises(evaluation.MapFormatError) as ctx:
                evaluation.load_map(broken(change), "map.geojson")
            self.assertIn(expected, str(ctx.exception))
            self.assertTrue(str(ctx.exception).startswith("map.geojson"))

    def test_cli_table_json_and_errors(self):
        with tempfile.TemporaryDirectory() as tmp:
            map_path, truth_path, bad_path = (os.path.join(tmp, n) for n in ("m.geojson", "t.geojson", "b.geojson"))
            for path, data in ((map_path, _map()), (truth_path, _truth())):
                with open(path, "w") as handle:
                    json.dump(data, handle)
            with open(bad_path, "w") as handle:
                handle.write("{not json")
            out = io.StringIO()
            with contextlib.redirect_stdout(out):
                self.assertEqual(cli_eval.main([map_path, truth_path, "--json"]), 0)
            scores = json.loads(out.getvalue())
            self.assertAlmostEqual(scores["classes"]["line_of_sight"]["detections"]["rms_m"], 0.1, delta=1e-12)
            out = io.StringIO()
            with contextlib.redirect_stdout(out):
                self.assertEqual(cli_eval.main([map_path, truth_path]), 0)
            self.assertIn("coverage", out.getvalue())
            self.assertIn("corners found within 0.5 m: 1 of 2", out.getvalue())
            err = io.StringIO()
            with contextlib.redirect_stderr(err):
                self.assertEqual(cli_eval.main([bad_path, truth_path]), 2)
                self.assertEqual(cli_eval.main([os.path.join(tmp, "none.geojson"), truth_path]), 2)
            self.assertIn("not valid JSON", err.getvalue())
            self.assertIn("no such file", err.getvalue())

    def test_missed_walls_say_which_walls_and_where(self):
        # the map covers x <= 5 + 0.283 of the LoS face (0.1 m off, 0.3 m tolerance) and none
        # of the hidden face (0.4 m off): 4.72 m and 10 m uncovered, the hidden wall first
        truth = _truth()
        truth["features"][0]["properties"]["name"] = "corridor_south"
        scores = evaluation.score_map(_map(), truth)
        missed = scores["missed_walls"]
        self.assertEqual([m["name"] for m in missed], [None, "corridor_south"])
        self.assertEqual([m["class"] for m in missed], ["hidden", "line_of_sight"])
        self.assertAlmostEqual(missed[0]["uncovered_m"], 10.0, delta=1e-9)
        self.assertAlmostEqual(missed[1]["uncovered_m"], 10.0 - 5.0 - math.sqrt(0.3**2 - 0.1**2), delta=0.011)
        self.assertAlmostEqual(missed[1]["length_m"], 10.0, delta=1e-9)
        self.assertAlmostEqual(missed[1]["uncovered_from"][0], 5.0 + math.sqrt(0.3**2 - 0.1**2), delta=0.011)
        self.assertAlmostEqual(missed[1]["uncovered_to"][0], 10.0, delta=0.011)
        self.assertEqual(missed[1]["uncovered_to"][1], -1.0)
        # a wall covered to within MISSED_MIN_M is not listed
        whole = _map()
        whole["features"].append(_feature("LineString", [[0, -1], [10, -1]], kind="wall",
                                          **{"class": "line_of_sight"}, confidence=1.0))
        self.assertEqual([m["class"] for m in evaluation.score_map(whole, truth)["missed_walls"]], ["hidden"])
        with tempfile.TemporaryDirectory() as tmp:
            map_path, truth_path = os.path.join(tmp, "m.geojson"), os.path.join(tmp, "t.geojson")
            for path, data in ((map_path, _map()), (truth_path, truth)):
                with open(path, "w") as handle:
                    json.dump(data, handle)
            self._list_option(map_path, truth_path, "--missed", ("true walls least covered (1 of 2", "(unnamed)"),
                              "corridor_south", "least covered")

    def test_error_sources_say_wrong_class_or_no_wall(self):
        # line of sight: ten detections 0.1 m off its face (squared 0.1 m²), two on the hidden
        # face 2 m behind it (8 m²: a wall mapped in the wrong class) and one 2 m in front of
        # it, 4 m from the hidden face (4 m²: near no true wall); hidden: all within 0.3 m
        truth = _truth()
        truth["features"][0]["properties"]["name"] = "corridor"
        truth["features"][1]["properties"]["name"] = "back"
        ours = _map()
        ours["features"][0]["geometry"]["coordinates"] += [[3.0, -3.0], [4.0, -3.0], [5.0, 1.0]]
        scores = evaluation.score_map(ours, truth)
        los = scores["classes"]["line_of_sight"]["detections"]
        self.assertAlmostEqual(los["rms_m"], math.sqrt(12.1 / 13), delta=1e-9)
        sources = los["error_sources"]
        self.assertEqual([(e["why"], e["wall"], e["count"]) for e in sources],
                         [("other_class", "back", 2), ("off_wall", "corridor", 1)])
        self.assertAlmostEqual(sources[0]["share"], 8.0 / 12.1, delta=1e-9)
        self.assertAlmostEqual(sources[1]["share"], 4.0 / 12.1, delta=1e-9)
        self.assertAlmostEqual(sources[0]["rms_m"], 2.0, delta=1e-9)
        self.assertEqual(scores["classes"]["hidden"]["detections"]["error_sources"], [])
        # a wider tolerance takes the 2 m detections for near misses: no source left
        wide = evaluation.score_map(ours, truth, coverage_tolerance_m=2.5)
        self.assertEqual(wide["classes"]["line_of_sight"]["detections"]["error_sources"], [])
        with tempfile.TemporaryDirectory() as tmp:
            map_path, truth_path = os.path.join(tmp, "m.geojson"), os.path.join(tmp, "t.geojson")
            for path, data in ((map_path, ours), (truth_path, truth)):
                with open(path, "w") as handle:
                    json.dump(data, handle)
            self._list_option(map_path, truth_path, "--sources",
                              ("66.1 %     2 detections, RMS 2.00 m, on a true wall of the other class: back",),
                              "nearest of the class: corridor", "squared error they carry")

    def test_align_takes_the_frames_turn_out(self):
        """A map exact in shape but drawn in a frame turned 1 deg about its first pose and
        shifted (0.10, -0.05) m: plain scoring sees the turn (a wall point 9.5 m along is
        0.17 m off), --align finds the move back and scores it as the exact map it is."""
        truth = _truth()
        truth["features"].append(_feature("MultiPoint", [[x + 0.5, -1.0] for x in range(10)], kind="detections",
                                          **{"class": "line_of_sight"}))
        truth["features"].append(_feature("MultiPoint", [[x + 0.5, -3.0] for x in range(10)], kind="detections",
                                          **{"class": "hidden"}))
        angle = math.radians(1.0)
        turn = np.array([[math.cos(angle), -math.sin(angle)], [math.sin(angle), math.cos(angle)]])
        shift = np.array([0.10, -0.05])
        turned = copy.deepcopy(truth)
        for feature in turned["features"]:
            points = np.asarray(feature["geometry"]["coordinates"], float)
            feature["geometry"]["coordinates"] = (points @ turn.T + shift).tolist()
        plain = evaluation.score_map(turned, truth)
        # the LoS points (x + 0.5, -1) land x sin(1 deg) + (1 - cos(1 deg)) - 0.05 from y = -1
        far_point = 9.5 * math.sin(angle) + (1.0 - math.cos(angle)) - 0.05
        self.assertAlmostEqual(plain["classes"]["line_of_sight"]["detections"]["max_m"], far_point, delta=1e-9)
        moved, move = evaluation.align_to_truth(turned, truth)
        self.assertAlmostEqual(move["rotation_deg"], -1.0, delta=1e-9)
        self.assertEqual(move["poses"], 10)
        scores = evaluation.score_map(moved, truth)
        for cls in evaluation.CLASSES:
            self.assertLess(scores["classes"][cls]["detections"]["rms_m"], 1e-9)
            self.assertAlmostEqual(scores["classes"][cls]["coverage"], 1.0, delta=1e-9)
        self.assertLess(scores["trajectory"]["rms_m"], 1e-9)
        self.assertEqual(scores["corners"]["found"], 2)
        with tempfile.TemporaryDirectory() as tmp:
            map_path, truth_path, short_path = (os.path.join(tmp, n) for n in ("m.geojson", "t.geojson", "s.geojson"))
            short = copy.deepcopy(turned)
            for feature in short["features"]:
                if feature["properties"]["kind"] == "trajectory":
                    feature["geometry"]["coordinates"] = feature["geometry"]["coordinates"][:7]
            for path, data in ((map_path, turned), (truth_path, truth), (short_path, short)):
                with open(path, "w") as handle:
                    json.dump(data, handle)
            status, out, _ = _cli(map_path, truth_path, "--align")
            self.assertEqual(status, 0)
            self.assertIn("aligned: the map turned -1.000 deg", out)
            status, out, _ = _cli(map_path, truth_path, "--align", "--json")
            self.assertAlmostEqual(json.loads(out)["aligned"]["rotation_deg"], -1.0, delta=1e-9)
            # trajectories of other lengths cannot be paired pose by pose: one clear error
            status, _, err = _cli(short_path, truth_path, "--align")
            self.assertEqual(status, 2)
            self.assertIn("trajectory has 7 poses and the truth's 10", err)

    def test_truth_scores_perfectly_against_itself(self):
        try:
            from gnuradio.thrumapper import building_sim, scene
        except ImportError:
            from thrumapper_local import building_sim, scene
        path = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "examples", "scenes",
                            "paper_4_4_corridor_corner.yaml")
        truth = building_sim.truth_geojson(scene.load_scene(path))
        # Detections exactly on the faces: zero error.
        points = {c: [] for c in evaluation.CLASSES}
        for feature in truth["features"]:
            if feature["properties"]["kind"] == "wall":
                a, b = np.array(feature["geometry"]["coordinates"])
                points[feature["properties"]["class"]].append(((a + b) / 2).tolist())
        as_map = copy.deepcopy(truth)
        for cls, pts in points.items():
            as_map["features"].append(_feature("MultiPoint", pts, kind="detections", **{"class": cls}))
        scores = evaluation.score_map(as_map, truth)
        for cls in evaluation.CLASSES:
            self.assertAlmostEqual(scores["classes"][cls]["detections"]["rms_m"], 0.0, delta=1e-12)
            self.assertAlmostEqual(scores["classes"][cls]["coverage"], 1.0, delta=1e-9)
            self.assertEqual(scores["classes"][cls]["false_wall_length_m"], 0.0)
        self.assertEqual(scores["corners"]["found"], scores["corners"]["truth"])
        self.assertAlmostEqual(scores["trajectory"]["rms_m"], 0.0)
        self.assertEqual(scores["missed_walls"], [])


if __name__ == "__main__":
    gr_unittest.run(qa_evaluation)
