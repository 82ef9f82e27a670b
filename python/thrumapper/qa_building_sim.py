#!/usr/bin/env python3
#
# SPDX-License-Identifier: GPL-3.0-or-later
#
"""Tests of the simulated building against closed forms and hand-computed geometry."""

import contextlib
import copy
import importlib.util
import io
import json
import math
import os
import sys
import tempfile
import time

import numpy as np
from gnuradio import gr_unittest

try:
    from gnuradio.thrumapper import building_sim, scene as scene_mod
except ImportError:
    # Not installed (or the C++ extension is not built): import the sibling files as a package.
    _here = os.path.dirname(os.path.abspath(__file__))
    _spec = importlib.util.spec_from_file_location("thrumapper_local", os.path.join(_here, "__init__.py"),
                                                   submodule_search_locations=[_here])
    _package = importlib.util.module_from_spec(_spec)
    sys.modules["thrumapper_local"] = _package
    _spec.loader.exec_module(_package)
    from thrumapper_local import building_sim, scene as scene_mod

C = 299792458.0
SCENES = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "examples", "scenes")

# Only what a test asks for: every path kind off unless switched on.
NOTHING = {"direct": False, "reflections": False, "second_order": False, "diffuse": False, "edges": False,
           "clutter": False}


def _rotation(angle):
    return np.array([[math.cos(angle), -math.sin(angle)], [math.sin(angle), math.cos(angle)]])


def _closed_form_slab(eps, thickness_m, cos_theta, f_hz):
    """One-layer slab, TE: Fabry–Perot closed forms, written out independently of the code."""
    k0 = 2 * np.pi * f_hz / C
    sin2 = 1 - cos_theta**2
    q = np.sqrt(eps - sin2)
    r = (cos_theta - q) / (cos_theta + q)  # (1 - √εr)/(1 + √εr) at normal incidence
    delta = k0 * thickness_m * q
    e2 = np.exp(-2j * delta)
    gamma = r * (1 - e2) / (1 - r**2 * e2)
    transmission = (1 - r**2) * np.exp(-1j * delta) / (1 - r**2 * e2)
    # Relative to the same straight ray in free space.
    return gamma, transmission * np.exp(1j * k0 * thickness_m * cos_theta)


def _scene(walls, physics, *, radar=None, pose=(0.0, 0.0, 0.0), **extra):
    data = {
        "name": "test",
        "seed": 3,
        "radar": radar or {},
        "walls": walls,
        "trajectory": {"poses": [list(pose)]},
        "physics": {**NOTHING, **physics},
        "noise": "none",
    }
    data.update(extra)
    return scene_mod.load_scene(data)


class qa_building_sim(gr_unittest.TestCase):
    def test_radar_convention_matches_radar_description(self):
        scene = _scene([], {})
        radar = scene.radar
        angles = 2 * np.pi * np.arange(8) / 8
        np.testing.assert_allclose(radar.tx_elements_m, np.column_stack((-0.35 + 0.08 * np.cos(angles),
                                                                         0.08 * np.sin(angles))), atol=1e-15)
        np.testing.assert_allclose(radar.rx_elements_m, np.column_stack((0.35 + 0.08 * np.cos(angles),
                                                                         0.08 * np.sin(angles))), atol=1e-15)
        n = np.arange(128)
        np.testing.assert_allclose(radar.subcarrier_offsets_hz, (n - 63.5) * 120e6 / 128)
        self.assertAlmostEqual(radar.carrier_hz, 2.44e9)

    def test_image_method_delay_of_one_wall(self):
        # A metal wall (Γ = -1 at every frequency) so that the phase is the geometry alone.
        wall = {"segment": [[-3.0, -1.2], [4.0, -0.9]], "material": "metal"}
        pose = (0.4, 0.3, 0.25)
        scene = _scene([wall], {"reflections": True}, pose=pose)
        k, m = 2, 5
        world = lambda p: _rotation(pose[2]) @ p + np.array(pose[:2])  # noqa: E731
        tx = world(scene.radar.tx_elements_m[k])
        rx = world(scene.radar.rx_elements_m[m])
        # Mirror the TX element in the wall's face toward it (centre line offset by 1 mm).
        a, b = np.array(wall["segment"][0]), np.array(wall["segment"][1])
        u = (b - a) / np.hypot(*(b - a))
        normal = np.array([-u[1], u[0]])
        side = np.sign((tx - a) @ normal)
        face_point = a + side * 0.001 * normal
        mirror = tx - 2 * ((tx - face_point) @ normal) * normal
        length = np.hypot(*(rx - mirror))

        channel = building_sim.channel_matrix_at_pose(scene, pose)[k, m]
        f = scene.radar.frequencies_hz
        slope = np.polyfit(f, np.unwrap(np.angle(channel)), 1)[0]
        self.assertLess(abs(-slope / (2 * np.pi) - length / C), 1e-14)  # 3 µm of path
        # And the whole response: -λ/(4πL)·e^{-j2πfL/c}.
        expected = -(C / f) / (4 * np.pi * length) * np.exp(-2j * np.pi * f * length / C)
        np.testing.assert_allclose(channel, expected, rtol=1e-9, atol=0)

    def test_oblique_plasterboard_reflection_matches_slab_formula(self):
        wall = {"segment": [[-3.0, -1.075], [3.0, -1.075]], "material": "plasterboard"}
        scene = _scene([wall], {"reflections": True})
        k, m = 0, 4  # TX element at (-0.27, 0), RX element at (0.27, 0)
        tx, rx = scene.radar.tx_elements_m[k], scene.radar.rx_elements_m[m]
        face_y = -1.0
        mirror = np.array([tx[0], 2 * face_y - tx[1]])
        length = np.hypot(*(rx - mirror))
        cos_theta = (tx[1] - face_y + rx[1] - face_y) / length
        f = scene.radar.frequencies_hz
        eps, thickness = scene_mod.MATERIAL_PRESETS["plasterboard"].layers[0]
        gamma, _ = _closed_form_slab(eps, thickness, cos_theta, f)
        channel = building_sim.channel_matrix_at_pose(scene, (0, 0, 0))[k, m]
        measured = channel / ((C / f) / (4 * np.pi * length) * np.exp(-2j * np.pi * f * length / C))
        np.testing.assert_allclose(measured, gamma, rtol=0, atol=1e-5)

    def test_door_gap_removes_the_specular_path(self):
        # The specular point of the centre pair on a wall 1 m to the right is at x = 0: a door
        # 0.9 m wide centred there (4 m along the wall) takes it away; a closed door puts back
        # a reflection with the leaf's own coefficient.
        wall = [{"name": "w", "segment": [[-4.0, -1.075], [4.0, -1.075]], "material": "plasterboard"}]
        physics = {"reflections": True}
        kinds = lambda sc: [p for p in building_sim.path_truth(sc, (0, 0, 0)) if p["kind"] == "wall"]  # noqa: E731
        self.assertEqual(len(kinds(_scene(wall, physics))), 1)
        self.assertEqual(kinds(_scene(wall, physics, doors=[{"wall": "w", "position_m": 4.0, "width_m": 0.9}])), [])
        closed = kinds(_scene(wall, physics, doors=[{"wall": 0, "position_m": 4.0, "width_m": 0.9,
                                                      "material": "wood"}]))
        self.assertEqual(len(closed), 1)
        wood = scene_mod.MATERIAL_PRESETS["wood"]
        eps, d = wood.layers[0]
        # The leaf (4 cm) sits on the wall's centre line: its face is 1.055 m away.
        length = 2 * math.hypot(0.35, 1.075 - d / 2)
        self.assertAlmostEqual(closed[0]["length_m"], length, delta=1e-12)
        gamma, _ = _closed_form_slab(eps, d, 2 * (1.075 - d / 2) / length, 2.44e9)
        self.assertAlmostEqual(closed[0]["amplitude"], C / 2.44e9 / (4 * np.pi * length) * abs(gamma), delta=1e-9)

    def test_slab_reflection_at_normal_incidence(self):
        f = np.linspace(2.38e9, 2.50e9, 7)
        for name in ("plasterboard", "concrete", "glass", "brick"):
            material = scene_mod.MATERIAL_PRESETS[name]
            eps, d = material.layers[0]
            n = np.sqrt(eps)
            r = (1 - n) / (1 + n)
            e2 = np.exp(-2j * (2 * np.pi * f / C) * n * d)
            closed = r * (1 - e2) / (1 - r**2 * e2)
            gamma, _ = building_sim.slab_coefficients(material, 1.0, f)
            np.testing.assert_allclose(gamma, closed, rtol=1e-12, atol=1e-14, err_msg=name)
        # A slab cut in two identical layers is the same slab (transfer-matrix product).
        eps = complex(4.0, -0.3)
        whole = scene_mod.Material("whole", ((eps, 0.12),))
        halves = scene_mod.Material("halves", ((eps, 0.05), (eps, 0.07)))
        for cos_theta in (1.0, 0.6, 0.2):
            for a, b in zip(building_sim.slab_coefficients(whole, cos_theta, f),
                            building_sim.slab_coefficients(halves, cos_theta, f)):
                np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-14)
        # Through the channel: TX and RX 1 cm apart facing a wall 2 m away (0.14° off normal).
        radar = {"tx_elements": [[-0.005, 0.0]], "rx_elements": [[0.005, 0.0]]}
        scene = _scene([{"segment": [[-4, -2.075], [4, -2.075]], "material": "plasterboard"}],
                       {"reflections": True}, radar=radar)
        f = scene.radar.frequencies_hz
        length = np.hypot(0.01, 4.0)
        eps, d = scene_mod.MATERIAL_PRESETS["plasterboard"].layers[0]
        n = np.sqrt(eps)
        r = (1 - n) / (1 + n)
        e2 = np.exp(-2j * (2 * np.pi * f / C) * n * d)
        closed = r * (1 - e2) / (1 - r**2 * e2)
        channel = building_sim.channel_matrix_at_pose(scene, (0, 0, 0))[0, 0]
        measured = channel / ((C / f) / (4 * np.pi * length) * np.exp(-2j * np.pi * f * length / C))
        np.testing.assert_allclose(measured, closed, atol=2e-5)

    def test_power_through_a_plasterboard_wall(self):
        wall = [{"segment": [[0.0, -3.0], [0.0, 3.0]], "material": "plasterboard"}]
        eps, d = scene_mod.MATERIAL_PRESETS["plasterboard"].layers[0]
        for rx_y in (0.0, 0.9):
            radar = {"tx_elements": [[-1.0, 0.0]], "rx_elements": [[1.0, rx_y]]}
            through = _scene(wall, {"direct": True}, radar=radar)
            free = _scene([], {"direct": True}, radar=radar)
            f = through.radar.frequencies_hz
            h_wall = building_sim.channel_matrix_at_pose(through, (0, 0, 0))[0, 0]
            h_free = building_sim.channel_matrix_at_pose(free, (0, 0, 0))[0, 0]
            cos_theta = 2.0 / math.hypot(2.0, rx_y)
            _, transmission = _closed_form_slab(eps, d, cos_theta, f)
            np.testing.assert_allclose(np.abs(h_wall) ** 2 / np.abs(h_free) ** 2, np.abs(transmission) ** 2,
                                       rtol=1e-5)
            np.testing.assert_allclose(h_wall / h_free, transmission, atol=1e-5)
            # The wall slows the wave: its extra group delay is about d(√εr' − 1)/c at normal incidence.
            extra_delay = -np.polyfit(2 * np.pi * f, np.unwrap(np.angle(h_wall / h_free)), 1)[0]
            if rx_y == 0.0:
                self.assertGreater(extra_delay, 0.1e-9)
                self.assertLess(extra_delay, 0.6e-9)

    def test_hidden_wall_is_weaker_and_later(self):
        scene = scene_mod.load_scene(os.path.join(SCENES, "paper_4_3_hidden_1p5m.yaml"))
        paths = building_sim.path_truth(scene, scene.poses[0])
        los = [p for p in paths if p["kind"] == "wall"][0]
        hidden = [p for p in paths if p["kind"] == "wall_through"][0]
        # Geometry by hand: faces at 0.6 m and 2.25 m, array centres at ±0.35 m.
        self.assertAlmostEqual(los["delay_s"], 2 * math.hypot(0.35, 0.6) / C, delta=1e-15)
        self.assertAlmostEqual(hidden["delay_s"], 2 * math.hypot(0.35, 2.25) / C, delta=1e-15)
        self.assertAlmostEqual(los["aoa_deg"], math.degrees(math.atan2(-0.6, -0.35)) % 360, delta=1e-9)
        self.assertAlmostEqual(hidden["aoa_deg"], math.degrees(math.atan2(-2.25, -0.35)) % 360, delta=1e-9)
        self.assertEqual(hidden["walls_crossed"], 2)
        level_db = 20 * math.log10(hidden["amplitude"] / los["amplitude"])
        self.assertTrue(-30.0 <= level_db <= -15.0, f"hidden wall {level_db:.1f} dB below the LoS wall")
        direct = [p for p in paths if p["kind"] == "direct"][0]
        self.assertAlmostEqual(direct["delay_s"], 0.7 / C, delta=1e-16)
        self.assertAlmostEqual(direct["aoa_deg"], 180.0, delta=1e-9)

    def test_dihedral_corner_returns_energy_where_a_flat_wall_does_not(self):
        wall_a = {"segment": [[0.0, 0.0], [2.0, 0.0]], "material": "plasterboard"}
        wall_b = {"segment": [[0.0, 0.0], [0.0, 2.0]], "material": "plasterboard"}
        # 4 m from the corner on its bisector, 45° off both walls' normals; the robot is turned
        # 30° away from the corner so that its baseline is not radial to it.
        distance = 4.0
        pose = (distance / math.sqrt(2), distance / math.sqrt(2), math.radians(225.0 + 30.0))
        physics = {"reflections": True, "second_order": True}
        flat = _scene([wall_a], physics, pose=pose)
        corner = _scene([wall_a, wall_b], physics, pose=pose)
        h_flat = building_sim.channel_matrix_at_pose(flat, pose)
        h_corner = building_sim.channel_matrix_at_pose(corner, pose)
        # The flat wall's specular point lies beyond its end: nothing comes back.
        self.assertEqual(float(np.sum(np.abs(h_flat) ** 2)), 0.0)
        # The corner retro-reflects: two bounces at 45° over about twice the range.
        f = corner.radar.frequencies_hz
        eps, d = scene_mod.MATERIAL_PRESETS["plasterboard"].layers[0]
        gamma45, _ = _closed_form_slab(eps, d, math.cos(math.radians(45.0)), f)
        inner = np.array([0.075, 0.075])  # where the two inner faces meet
        one_path = (C / f) / (4 * np.pi * 2 * np.hypot(*(np.array(pose[:2]) - inner))) * np.abs(gamma45) ** 2
        ratio = np.mean(np.abs(h_corner) ** 2) / np.mean(one_path**2)
        print(f"\ncorner at 45° aspect, 4 m: {10 * math.log10(ratio):.1f} dB re one double bounce; flat wall: none")
        self.assertTrue(0.25 < ratio < 4.0, f"corner power {10 * math.log10(ratio):.1f} dB re one path")
        # Between the array centres: perpendicular faces mirror the TX centre through the
        # inner corner, so the path length is |2·corner − tx − rx|, and it arrives from the corner.
        world = _rotation(pose[2])
        tx = world @ corner.radar.tx_centre_m + np.array(pose[:2])
        rx = world @ corner.radar.rx_centre_m + np.array(pose[:2])
        paths = [p for p in building_sim.path_truth(corner, pose) if p["kind"] == "corner"]
        self.assertEqual(len(paths), 1)
        self.assertAlmostEqual(paths[0]["length_m"], np.hypot(*(2 * inner - tx - rx)), delta=1e-9)
        bearing = (math.degrees(math.atan2(*(inner - rx)[::-1])) - math.degrees(pose[2])) % 360
        gap = abs((paths[0]["aoa_deg"] - bearing + 180) % 360 - 180)
        self.assertLess(gap, 6.0)

    def test_reciprocity(self):
        path = os.path.join(SCENES, "paper_4_4_corridor_corner.yaml")
        import yaml

        with open(path) as handle:
            data = yaml.safe_load(handle)
        forward = scene_mod.load_scene(copy.deepcopy(data))
        radar = forward.radar
        data["radar"] = {"tx_elements": radar.rx_elements_m.tolist(), "rx_elements": radar.tx_elements_m.tolist()}
        swapped = scene_mod.load_scene(data)
        for pose in (forward.poses[3], forward.poses[-1]):
            h = building_sim.channel_matrix_at_pose(forward, pose)
            h_swapped = building_sim.channel_matrix_at_pose(swapped, pose)
            self.assertGreater(np.max(np.abs(h)), 0.0)
            np.testing.assert_allclose(h_swapped.transpose(1, 0, 2), h, rtol=0, atol=1e-10 * np.max(np.abs(h)))
        # Every kind of path took part.
        kinds = {p["kind"] for p in building_sim.path_truth(forward, forward.poses[-1], include_diffuse=True)}
        for kind in ("direct", "wall", "wall_through", "corner", "clutter", "diffuse", "edge"):
            self.assertIn(kind, kinds)

    def test_null_steering_suppresses_direct_coupling(self):
        plain = scene_mod.load_scene(os.path.join(SCENES, "paper_4_1_direct.yaml"))
        nulled = scene_mod.load_scene(os.path.join(SCENES, "paper_4_1_direct_null.yaml"))
        pose = plain.poses[0]
        weights = building_sim.scene_tx_weights(nulled)
        ones = np.ones(plain.radar.num_tx) * np.linalg.norm(weights) / math.sqrt(plain.radar.num_tx)
        power_ones = np.sum(np.abs(building_sim.channel_at_pose(plain, pose, ones)) ** 2)
        power_null = np.sum(np.abs(building_sim.channel_at_pose(nulled, pose)) ** 2)
        depth_db = 10 * math.log10(power_null / power_ones)
        print(f"\nnull depth with the spherical-wavefront design: {depth_db:.1f} dB")
        self.assertLess(depth_db, -30.0)
        # The paper's plane-wave eq. 9 at 0.7 m: a shallow null (DESIGN.md: about 8 dB).
        radar = plain.radar
        plane = building_sim.null_steering_weights(radar.tx_elements_m, radar.rx_elements_m, [radar.carrier_hz],
                                                   math.radians(270.0), wavefront="plane")
        plane *= np.linalg.norm(weights) / np.linalg.norm(plane)
        plane_db = 10 * math.log10(np.sum(np.abs(building_sim.channel_at_pose(plain, pose, plane)) ** 2) / power_ones)
        print(f"null depth with plane-wave eq. 9: {plane_db:.1f} dB")
        self.assertGreater(plane_db, -20.0)
        # The main lobe still points at 270°: within 6 dB of a pure beam of the same power.
        beam = building_sim.steering_vector(radar.tx_elements_m, math.radians(270.0), radar.carrier_hz)
        gain = abs(np.vdot(beam, weights)) / (np.linalg.norm(beam) * np.linalg.norm(weights))
        self.assertGreater(20 * math.log10(gain), -6.0)

    def test_impairments_and_reference_frames(self):
        gains_db = [0.0, 0.5, -0.3, 1.0, 0.0, -1.0, 0.2, 0.1]
        phases_deg = [0, 40, -70, 120, 10, -160, 90, 5]
        delays_ps = [0, 10, -20, 0, 30, 0, -5, 15]
        scene = _scene(
            [{"segment": [[-3, -0.775], [3, -0.775]]}], {"direct": True, "reflections": True},
            frames_per_pose=2,
            impairments={"system_delay_s": 25e-9, "rx": {"gain_db": gains_db, "phase_deg": phases_deg,
                                                         "delay_ps": delays_ps},
                         "rx_reference_frames": 3, "rx_reference_amplitude": 0.02},
        )
        result = building_sim.simulate_survey(scene, progress=False)
        f = scene.radar.frequencies_hz
        beta = (10 ** (np.array(gains_db) / 20) * np.exp(1j * np.radians(phases_deg)))[:, None] * np.exp(
            -2j * np.pi * np.outer(np.array(delays_ps) * 1e-12, f))
        system = np.exp(-2j * np.pi * f * 25e-9)
        self.assertEqual(result.frame_types, ["rx_reference"] * 3 + ["survey"] * 2)
        self.assertEqual(result.csi.dtype, np.complex64)
        for frame in range(3):
            np.testing.assert_allclose(result.csi[frame], beta * 0.02 * system, rtol=1e-6, atol=1e-9)
            self.assertTrue(np.all(np.isnan(result.poses_odometry[frame])))
        expected = beta * building_sim.channel_at_pose(scene, scene.poses[0]) * system
        for frame in (3, 4):
            np.testing.assert_allclose(result.csi[frame], expected, rtol=1e-5, atol=1e-9)
            np.testing.assert_allclose(result.poses_true[frame], scene.poses[0])

    def test_noise_power(self):
        scene = _scene([], {"direct": True}, frames_per_pose=50, noise={"power_db": -60})
        result = building_sim.simulate_survey(scene, progress=False)
        residual = result.csi - result.noiseless_csi[0]
        measured_db = 10 * math.log10(np.mean(np.abs(residual) ** 2))
        self.assertAlmostEqual(measured_db, -60.0, delta=0.2)  # 51200 samples: ±0.04 dB std

    def test_odometry_error_model(self):
        trajectory = {"waypoints": [[0, 0], [10, 0]], "step_m": 0.5}
        scene = _scene([], {}, odometry={"scale_error": 0.02})
        scene.poses = scene_mod._read_trajectory(trajectory)
        reported = building_sim.odometry_poses(scene, scene.poses)
        self.assertAlmostEqual(reported[-1, 0], 10.0 * 1.02, delta=1e-9)
        self.assertAlmostEqual(reported[-1, 1], 0.0, delta=1e-9)
        scene.odometry = {"scale_error": 0.0, "heading_drift_deg_per_m": 1.0, "position_noise_m": 0.0,
                          "heading_noise_deg": 0.0}
        reported = building_sim.odometry_poses(scene, scene.poses)
        self.assertAlmostEqual(math.degrees(reported[-1, 2]), 10.0, delta=1e-9)
        self.assertEqual(scene.poses.shape, (21, 3))

    def test_truth_map_of_hidden_wall_scene(self):
        scene = scene_mod.load_scene(os.path.join(SCENES, "paper_4_3_hidden_1p5m.yaml"))
        truth = building_sim.truth_geojson(scene)
        self.assertEqual(truth["type"], "FeatureCollection")
        self.assertEqual(truth["thrumapper:crs"], "local-metres")
        walls = [f for f in truth["features"] if f["properties"]["kind"] == "wall"]
        by_class = {f["properties"]["class"]: np.array(f["geometry"]["coordinates"]) for f in walls}
        self.assertEqual(sorted(by_class), ["hidden", "line_of_sight"])
        self.assertEqual(len(walls), 2)
        # The faces toward the robot, not the centre lines: y = -0.6 and y = -2.25.
        np.testing.assert_allclose(by_class["line_of_sight"][:, 1], -0.6, atol=1e-12)
        np.testing.assert_allclose(by_class["hidden"][:, 1], -2.25, atol=1e-12)
        trajectory = [f for f in truth["features"] if f["properties"]["kind"] == "trajectory"][0]
        self.assertEqual(trajectory["geometry"]["type"], "LineString")

    def test_truth_corners_of_corridor_scene(self):
        scene = scene_mod.load_scene(os.path.join(SCENES, "paper_4_4_corridor_corner.yaml"))
        truth = building_sim.truth_geojson(scene)
        corners = [f for f in truth["features"] if f["properties"]["kind"] == "corner"]
        positions = {tuple(np.round(f["geometry"]["coordinates"], 4)): f["properties"] for f in corners}
        # The LoS wall's face (y = -0.7) meets the end wall's face (x = 6.525): a concave corner in view.
        self.assertIn((6.525, -0.7), positions)
        self.assertEqual(positions[(6.525, -0.7)]["corner_type"], "concave")
        self.assertEqual(positions[(6.525, -0.7)]["class"], "line_of_sight")
        # The room's far corner (back face y = -2.35, end wall face x = 6.525) is seen through the LoS wall.
        self.assertEqual(positions[(6.525, -2.35)]["class"], "hidden")

    def test_truth_open_doorway_of_office_scene(self):
        """office_floor's north corridor wall (centre line y = 1.075, 15 cm) has one door left
        open, centred 17.2 m from the wall's first point (x = -3): the truth has one opening,
        across x = 13.75-14.65 m on the face toward the corridor (y = 1.0); its closed doors
        are walls (door leaves), not openings."""
        scene = scene_mod.load_scene(os.path.join(SCENES, "office_floor.yaml"))
        truth = building_sim.truth_geojson(scene)
        openings = [f for f in truth["features"] if f["properties"]["kind"] == "opening"]
        self.assertEqual(len(openings), 1)
        np.testing.assert_allclose(openings[0]["geometry"]["coordinates"], [[13.75, 1.0], [14.65, 1.0]], atol=1e-9)
        self.assertAlmostEqual(openings[0]["properties"]["width_m"], 0.9)
        self.assertEqual(openings[0]["properties"]["name"], "corridor_north")
        self.assertGreater(sum(1 for f in truth["features"] if f["properties"].get("door")), 0)

    def test_scene_errors_name_the_field(self):
        base = {"walls": [{"segment": [[0, -1], [4, -1]]}], "trajectory": {"poses": [[1, 0, 0]]}}
        cases = [
            ({"walls": [{"segment": [[0, -1], [4, -1]], "material": "plaster"}]}, "walls[0].material"),
            ({"walls": [{"segment": [[0, -1], [4, -1]], "thicknes_m": 0.1}]}, "walls[0].thicknes_m"),
            ({"doors": [{"wall": 0, "position_m": 3.9, "width_m": 0.9}]}, "doors[0].position_m"),
            ({"doors": [{"wall": "nope", "position_m": 1, "width_m": 0.9}]}, "doors[0].wall"),
            ({"trajectory": {"poses": [[1, 0]]}}, "trajectory.poses[0]"),
            ({"trajectory": {"waypoints": [[0, 0], [1, 0]]}}, "trajectory.step_m"),
            ({"trajectory": {"poses": [[1, -0.95, 0]]}}, "trajectory"),
            ({"radar": {"subcarriers": 0}}, "radar.subcarriers"),
            ({"tx_weights": {"mode": "null_steer"}}, "tx_weights.main_lobe_deg"),
            ({"impairments": {"rx": {"gain_db": [1, 2]}}}, "impairments.rx.gain_db"),
            ({"clutter": [{"position_m": [1, 1], "preset": "sofa"}]}, "clutter[0].preset"),
            ({"materials": {"x": {"relative_permittivity": [2.0, 0.5], "thickness_m": 0.1}}},
             "materials.x.relative_permittivity"),
        ]
        for change, field in cases:
            data = {**base, **change}
            with self.assertRaises(scene_mod.SceneError) as ctx:
                scene_mod.load_scene(data)
            self.assertTrue(str(ctx.exception).startswith(field), f"{field!r} not first in: {ctx.exception}")
        with self.assertRaises(scene_mod.SceneError) as ctx:
            scene_mod.load_scene({"walls": []})
        self.assertTrue(str(ctx.exception).startswith("trajectory"))

    def test_every_example_scene_loads(self):
        names = sorted(n for n in os.listdir(SCENES) if n.endswith(".yaml"))
        self.assertGreaterEqual(len(names), 8)
        for name in names:
            scene = scene_mod.load_scene(os.path.join(SCENES, name))
            building_sim.truth_geojson(scene)
            self.assertEqual(scene.name, name[: -len(".yaml")])

    def test_office_floor_timing(self):
        scene = scene_mod.load_scene(os.path.join(SCENES, "office_floor.yaml"))
        started = time.perf_counter()
        result = building_sim.simulate_survey(scene, progress=False)
        elapsed = time.perf_counter() - started
        print(f"\noffice_floor: {scene.num_poses} poses x {scene.frames_per_pose} frames, K=M=8, N=128: "
              f"{elapsed:.2f} s ({1e3 * elapsed / scene.num_poses:.1f} ms per pose)")
        self.assertEqual(result.csi.shape, (4 + 400, 8, 128))
        self.assertEqual(result.frame_types[:4], ["rx_reference"] * 4)
        self.assertTrue(np.all(np.isfinite(result.csi)))
        # Odometry drifts, but not wildly over 20 m.
        drift = np.hypot(*(result.poses_odometry[-1, :2] - result.poses_true[-1, :2]))
        self.assertTrue(0.0 < drift < 2.0)
        self.assertLess(elapsed, 600.0)  # a report, not a benchmark

    def test_cli_writes_survey_and_truth(self):
        try:
            from gnuradio.thrumapper import cli_sim, survey
        except ImportError:
            try:
                from thrumapper_local import cli_sim, survey
            except ImportError as err:
                self.skipTest(f"survey I/O unavailable: {err}")
        with tempfile.TemporaryDirectory() as out:
            printed = io.StringIO()
            with contextlib.redirect_stdout(printed):
                code = cli_sim.main([os.path.join(SCENES, "paper_4_2_wall_0p7m.yaml"), "--out", out, "--quiet"])
            self.assertEqual(code, 0)
            self.assertIn(os.path.join(out, "paper_4_2_wall_0p7m.sigmf-meta"), printed.getvalue())
            recording = survey.read_survey(os.path.join(out, "paper_4_2_wall_0p7m"))
            self.assertEqual(recording.csi.shape, (4, 8, 128))
            self.assertEqual(recording.frame_types, ["survey"] * 4)
            self.assertAlmostEqual(recording.system_delay_s, 20e-9)
            self.assertEqual(recording.wall_model, {"relative_permittivity": 2.73, "thickness_m": 0.15})
            with open(os.path.join(out, "paper_4_2_wall_0p7m.truth.geojson")) as handle:
                truth = json.load(handle)
            self.assertEqual(truth["thrumapper:crs"], "local-metres")
            errors = io.StringIO()
            with contextlib.redirect_stderr(errors):
                self.assertEqual(cli_sim.main([os.path.join(out, "missing.yaml"), "--out", out, "--quiet"]), 2)
            self.assertIn("no such scene file", errors.getvalue())


if __name__ == "__main__":
    gr_unittest.run(qa_building_sim)
