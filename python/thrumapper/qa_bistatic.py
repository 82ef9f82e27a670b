#!/usr/bin/env python3
#
# SPDX-License-Identifier: GPL-3.0-or-later
#
"""Bistatic geometry and the slab echo model, against closed forms and the simulator."""

import math

import numpy as np
from gnuradio import gr_unittest

from gnuradio.thrumapper import bistatic, building_sim, echo_model, scene

C = bistatic.SPEED_OF_LIGHT_M_S
TX = np.array([-0.35, 0.0])
RX = np.array([0.35, 0.0])


def metal_scene(segment, poses_deg=((0.0, 0.0, 0.0),), physics=None, **extra):
    data = {
        "name": "t", "seed": 5,
        "radar": {"elements": 8, "radius_m": 0.08, "baseline_m": 0.7, "carrier_hz": 2.44e9,
                  "bandwidth_hz": 120e6, "subcarriers": 64},
        "walls": [{"segment": s, "material": "metal"} for s in segment],
        "trajectory": {"poses_deg": [list(p) for p in poses_deg]},
        "frames_per_pose": 1, "noise": "none",
        "physics": physics or {"direct": False, "diffuse": False, "edges": False, "clutter": False},
    }
    data.update(extra)
    return scene.load_scene(data)


def walls_alone(segments, second_order):
    """A one-pose scene of plasterboard walls with reflections only (no direct path, clutter,
    edges, diffuse scattering, impairments or noise): (scene, its CSI at the pose (M, N), an
    EchoModel with the scene's TX weights)."""
    sc = scene.load_scene({
        "name": "t", "seed": 5,
        "radar": {"elements": 8, "radius_m": 0.08, "baseline_m": 0.7, "carrier_hz": 2.44e9,
                  "bandwidth_hz": 120e6, "subcarriers": 64},
        "walls": [{"segment": seg, "material": "plasterboard"} for seg in segments],
        "trajectory": {"poses_deg": [[0, 0, 0]]}, "frames_per_pose": 1, "noise": "none",
        "tx_weights": {"mode": "null_steer", "main_lobe_deg": 270},
        "physics": {"direct": False, "diffuse": False, "edges": False, "clutter": False,
                    "second_order": second_order}})
    weights = building_sim.scene_tx_weights(sc)
    h_sim = building_sim.channel_at_pose(sc, sc.poses[0], tx_weights=weights)
    model = echo_model.EchoModel(sc.radar.tx_elements_m, sc.radar.rx_elements_m, weights, sc.radar.carrier_hz,
                                 sc.radar.subcarrier_offsets_hz)
    return sc, h_sim, model


class qa_bistatic(gr_unittest.TestCase):
    def test_known_wall(self):
        """The paper's §4.2 wall, face 0.7 m to the right: 2·sqrt(0.7² + 0.35²)/c and the
        bearing of the midpoint from the RX give the point (0, -0.7) and a wall along x."""
        delay_s = 2.0 * math.hypot(0.7, 0.35) / C
        aoa_rad = math.atan2(-0.7, -0.35)
        point, normal = bistatic.reflection_point(aoa_rad, delay_s, TX, RX)
        self.assertLess(np.hypot(*(point - [0.0, -0.7])), 1e-6)
        self.assertLess(abs(math.atan2(normal[1], normal[0]) - math.pi / 2), 1e-6)
        self.assertAlmostEqual(math.degrees(aoa_rad) % 360, 243.4349, places=3)

    def test_skewed_wall_against_the_simulator(self):
        """A metal wall skewed 15° from the trajectory, its face traced by the simulator's image
        method between the array centres: the echo's (θ, τ) give back the simulator's
        reflection point to 1 mm and the wall's orientation to 1 mm over a metre."""
        angle = math.radians(15.0)
        direction = np.array([math.cos(angle), math.sin(angle)])
        centre = np.array([0.4, -1.6])
        sc = metal_scene([[list(centre - 4 * direction), list(centre + 4 * direction)]],
                         poses_deg=((0.2, 0.1, 7.0),))
        pose = sc.poses[0]
        truth = [t for t in building_sim.path_truth(sc, pose) if t["kind"] == "wall"]
        self.assertEqual(len(truth), 1)
        t = truth[0]
        point_r, normal_r = bistatic.reflection_point(math.radians(t["aoa_deg"]), t["delay_s"], TX, RX)
        point_w = bistatic.robot_to_world(point_r, pose)
        self.assertLess(np.hypot(*(point_w - np.asarray(t["points_m"][0]))), 1e-3)
        normal_w = bistatic.rotate(normal_r, pose[2])
        wall_normal = np.array([-direction[1], direction[0]])  # toward the robot (+y side)
        self.assertLess(math.acos(min(1.0, abs(float(normal_w @ wall_normal)))), 1e-3)
        # the face is the centre line moved toward the robot by half the thickness
        face_offset = (point_w - centre) @ wall_normal
        self.assertAlmostEqual(face_offset, sc.walls[0].thickness_m / 2, delta=1e-3)

    def test_round_trip_many_walls(self):
        """specular_path (image method) and reflection_point (ellipse ∩ ray) invert each other
        for walls on every side at every orientation that faces both arrays."""
        rng = np.random.default_rng(11)
        done = 0
        for _ in range(400):
            phi = rng.uniform(-math.pi, math.pi)
            normal = np.array([math.cos(phi), math.sin(phi)])
            distance = rng.uniform(0.3, 8.0)
            face = -normal * distance  # the wall's normal points back to the origin
            try:
                aoa, delay, point = bistatic.specular_path(face, normal, TX, RX)
            except bistatic.GeometryError:
                continue
            p, n = bistatic.reflection_point(aoa, delay, TX, RX)
            self.assertLess(np.hypot(*(p - point)), 1e-9)
            self.assertLess(np.hypot(*(n - normal)), 1e-9)
            done += 1
        self.assertGreater(done, 300)

    def test_impossible_echoes(self):
        direct_s = bistatic.direct_delay_s(TX, RX)
        self.assertAlmostEqual(direct_s, 0.7 / C, delta=1e-18)
        with self.assertRaisesRegex(bistatic.GeometryError, "not longer than the direct path"):
            bistatic.reflection_point(math.radians(270), 0.9 * direct_s, TX, RX)
        with self.assertRaisesRegex(bistatic.GeometryError, "not longer than the direct path"):
            bistatic.reflection_point(math.radians(270), direct_s, TX, RX)
        with self.assertRaisesRegex(bistatic.GeometryError, "NaN"):
            bistatic.reflection_point(float("nan"), 5e-9, TX, RX)
        with self.assertRaises(bistatic.GeometryError):
            bistatic.specular_path([0.0, 0.0], [0.0, 1.0], [-0.35, 1.0], [0.35, -1.0])  # arrays on both sides

    def test_double_bounce_against_the_simulator(self):
        """A metal corridor: the simulator's second-order path and the double imaging agree."""
        sc = metal_scene([[[-6, -1.0], [6, -1.0]], [[-6, 1.3], [6, 1.3]]])
        doubles = [t for t in building_sim.path_truth(sc, sc.poses[0]) if t["kind"] == "double"]
        self.assertEqual(len(doubles), 2)
        south = (np.array([0.0, -1.0 + 0.001]), np.array([0.0, 1.0]))  # faces: metal is 2 mm thick
        north = (np.array([0.0, 1.3 - 0.001]), np.array([0.0, -1.0]))
        predicted = [bistatic.double_bounce_path(*south, *north, TX, RX), bistatic.double_bounce_path(*north, *south, TX, RX)]
        for p in predicted:
            self.assertIsNotNone(p)
            match = min(doubles, key=lambda t: abs(t["delay_s"] - p[1]) + abs(math.radians(t["aoa_deg"]) - p[0]))
            self.assertAlmostEqual(match["delay_s"], p[1], delta=1e-14)
            self.assertAlmostEqual(match["aoa_deg"], math.degrees(p[0]), delta=1e-6)

    def test_echo_model_matches_the_simulator(self):
        """echo_csi (image method per element pair, slab Γ at each pair's incidence, TX weights)
        is the simulator's channel for a lone slab wall: an independent implementation of the
        same physics (reflections only, no impairments, no noise)."""
        sc, h_sim, model = walls_alone([[[-8, -1.2], [8, -1.2]]], second_order=False)
        face = np.array([0.0, -1.2 + 0.075])
        h_model = model.echo_csi(face, [0.0, 1.0], scene.MATERIAL_PRESETS["plasterboard"])
        error = np.linalg.norm(h_model - h_sim) / np.linalg.norm(h_sim)
        self.assertLess(error, 1e-4)

    def test_segment_crossings(self):
        """A leg crosses a wall only properly: an X crosses, a T whose stem ends on the bar
        does not, nor parallel or disjoint segments; the float form and the array form agree."""
        cases = [((0, 0, 2, 2, 0, 2, 2, 0), True),    # an X
                 ((0, 0, 1, 1, 0, 2, 2, 0), False),   # the stem ends on the bar: touching
                 ((0, 0, 2, 0, 0, 1, 2, 1), False),   # parallel
                 ((0, 0, 1, 0, 2, -1, 2, 1), False),  # short of the wall
                 ((-0.35, 0, 0.3, -2.2, -3, -1, 3, -1), True)]  # a TX leg through a corridor wall
        for args, expected in cases:
            self.assertEqual(bistatic.segment_crosses(*map(float, args)), expected, args)
            p = np.array(args, float).reshape(4, 2)
            self.assertEqual(bool(bistatic.segments_cross(p[0], p[1], p[2], p[3])), expected, args)

    def test_segment_distances(self):
        """The gap between two segments: 0 across an X, the perpendicular from an end to the
        other's middle, end to end when neither end faces the other; both orders the same,
        and one row per pair when broadcast."""
        cases = [((0, 0, 2, 2, 0, 2, 2, 0), 0.0),          # an X
                 ((0, 0, 2, 0, 0, 1, 2, 1), 1.0),          # parallel, 1 m apart
                 ((0, 0, 1, 0, 2, -1, 2, 1), 1.0),         # a T short of its bar by 1 m
                 ((0, 0, 1, 0, 4, 4, 5, 4), 5.0),          # end (1, 0) to end (4, 4)
                 ((10.04 - 0.35, 0.0, 10.04 + 0.35, 0.0, 10.31, 0.74, 10.43, 0.04), math.hypot(0.04, 0.04))]  # a wall at the RX
        for args, expected in cases:
            p = np.array(args, float).reshape(4, 2)
            self.assertAlmostEqual(float(bistatic.segments_distance(p[0], p[1], p[2], p[3])), expected, places=9,
                                   msg=str(args))
            self.assertAlmostEqual(float(bistatic.segments_distance(p[2], p[3], p[0], p[1])), expected, places=9,
                                   msg=str(args))
        p = np.array([c for c, _ in cases], float).reshape(-1, 4, 2)
        np.testing.assert_allclose(bistatic.segments_distance(p[:, 0], p[:, 1], p[:, 2], p[:, 3]),
                                   [e for _, e in cases], atol=1e-9)

    def test_hidden_wall_echo_matches_the_simulator(self):
        """A plasterboard wall 2 m behind another: echo_csi of the front wall plus echo_csi of
        the back one with both of its legs through the front wall (its insertion T at each leg's
        incidence) is the simulator's channel; without the crossing the model is far off (T²
        is most of the hidden echo's size and phase). echo_csi is the C++ core (slab_echo): the
        simulator is the independent implementation."""
        sc, h_sim, model = walls_alone([[[-8, -1.2], [8, -1.2]], [[-8, -3.2], [8, -3.2]]], second_order=False)
        plaster = scene.MATERIAL_PRESETS["plasterboard"]
        up = np.array([0.0, 1.0])
        front = model.echo_csi([0.0, -1.2 + 0.075], up, plaster)
        back = model.echo_csi([0.0, -3.2 + 0.075], up, plaster, ((np.array([0.0, -1.2]), up, plaster),))
        self.assertLess(np.linalg.norm(front + back - h_sim) / np.linalg.norm(h_sim), 1e-9)
        alone = model.echo_csi([0.0, -3.2 + 0.075], up, plaster)
        self.assertGreater(np.linalg.norm(front + alone - h_sim) / np.linalg.norm(h_sim), 0.3)
        # the numpy form of the model (the benchmark's reference) agrees
        reference = model.echo_csi_reference([0.0, -3.2 + 0.075], up, plaster, ((np.array([0.0, -1.2]), up, plaster),))
        self.assertLess(np.linalg.norm(back - reference) / np.linalg.norm(back), 1e-9)
        # a wall the model cannot place: one clear error, not NaN in the CSI
        with self.assertRaisesRegex(ValueError, "nonzero normal"):
            model.echo_csi([0.0, -1.125], [0.0, 0.0], plaster)
        with self.assertRaisesRegex(ValueError, "finite face point"):
            model.echo_csi([np.nan, -1.125], up, plaster)
        with self.assertRaisesRegex(ValueError, "crossed wall 0"):
            model.echo_csi([0.0, -3.125], up, plaster, ((np.array([np.nan, -1.2]), up, plaster),))

    def test_corner_echo_matches_the_simulator(self):
        """corner_csi (both bounce orders per element pair, Γ at each bounce's incidence, TX
        weights) with echo_csi of both faces is the simulator's channel for an L of two
        plasterboard walls, a concave corner 1.5 m ahead and 0.8 m to the right; and the
        corner of two perpendicular conductors answers from the image of TX through the
        corner point, 2C - TX, as a retro-reflector does."""
        sc, h_sim, model = walls_alone([[[-8, -0.9], [1.6, -0.9]], [[1.6, -0.9], [1.6, 3.0]]], second_order=True)
        plaster = scene.MATERIAL_PRESETS["plasterboard"]
        south, east = np.array([0.0, 1.0]), np.array([-1.0, 0.0])
        corner = np.array([1.6 - 0.075, -0.9 + 0.075])
        walls_only = model.echo_csi(corner, south, plaster) + model.echo_csi(corner, east, plaster)
        h_corner = model.corner_csi(corner, south, east, plaster)
        error = np.linalg.norm(walls_only + h_corner - h_sim) / np.linalg.norm(h_sim)
        without = np.linalg.norm(walls_only - h_sim) / np.linalg.norm(h_sim)
        self.assertLess(error, 1e-6)
        # the corner's echo is a real part of it (a weak one: two bounces): without it the
        # model is 1.7 % off
        self.assertGreater(without, 0.01)
        # the order of the faces does not matter (both bounce orders are summed)
        np.testing.assert_allclose(model.corner_csi(corner, east, south, plaster), h_corner, rtol=1e-12, atol=1e-18)
        # conductors, far off (the one-path fit is a far-field one) and uniform TX weights (a
        # steered beam's phase centre is off the array's centre): the apparent path is from
        # TX's image 2C - TX to RX
        uniform = echo_model.EchoModel(sc.radar.tx_elements_m, sc.radar.rx_elements_m, np.ones(8), sc.radar.carrier_hz,
                                       sc.radar.subcarrier_offsets_hz)
        tx, rx = uniform.tx_centre_m, uniform.rx_centre_m
        far = np.array([5.0, -2.5])
        image = 2.0 * far - tx
        theta, tau = uniform.apparent(uniform.corner_csi(far, south, east, None),
                                    math.atan2(*(image - rx)[::-1]), np.hypot(*(image - rx)) / C)
        self.assertAlmostEqual(tau, np.hypot(*(image - rx)) / C, delta=0.05e-9)
        self.assertAlmostEqual(math.degrees(theta) % 360, math.degrees(math.atan2(*(image - rx)[::-1])) % 360,
                               delta=1.0)
        # a corner whose face the arrays are behind is not seen
        self.assertEqual(np.abs(model.corner_csi(corner, south, -east, plaster)).max(), 0.0)

    def test_slab_shift_physics(self):
        """A metal wall's echo has one face: far from the radar its apparent position is the
        geometric one. A plasterboard slab's is shifted, within its two faces' delay span; the
        insertion delay of one crossing is near d(√εr − 1)/c (0.33 ns for 15 cm)."""
        tx_m = scene.uca_positions(8, 0.08, 0.0, -0.35, 0.0)
        rx_m = scene.uca_positions(8, 0.08, 0.0, 0.35, 0.0)
        offsets = scene.uniform_subcarriers(64, 120e6)
        model = echo_model.EchoModel(tx_m, rx_m, np.ones(8), 2.44e9, offsets)
        d_theta, d_tau = model.shift([0.0, -2.2], [0.0, 1.0], scene.MATERIAL_PRESETS["metal"])
        self.assertLess(abs(d_tau), 0.03e-9)
        self.assertLess(abs(math.degrees(d_theta)), 0.2)
        plaster = scene.MATERIAL_PRESETS["plasterboard"]
        _, d_tau = model.shift([0.0, -2.2], [0.0, 1.0], plaster)
        span = model.echo_span_s(plaster)
        self.assertAlmostEqual(span, 2 * 0.15 * math.sqrt(2.73) / C, delta=1e-15)
        self.assertLessEqual(abs(d_tau), span)
        self.assertGreater(abs(d_tau), 0.05e-9)
        t_s = echo_model.transmission_delay_s(plaster, 0.0, 2.44e9)
        self.assertAlmostEqual(t_s, 0.15 * (math.sqrt(2.73) - 1) / C, delta=0.08e-9)
        # a wall model with only the real part gets the nearest preset's loss
        material = echo_model.material_from({"relative_permittivity": 2.73, "thickness_m": 0.15})
        self.assertAlmostEqual(material.layers[0][0].imag, plaster.layers[0][0].imag, delta=1e-9)
        with self.assertRaisesRegex(ValueError, "unknown preset"):
            echo_model.material_from("plaster")


if __name__ == "__main__":
    gr_unittest.run(qa_bistatic)
