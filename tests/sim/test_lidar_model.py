"""The LiDAR measurement model (seed 001 §2.3.3–2.3.4) against hand-computed geometry, inverse ∘
forward = identity and its Jacobians against central finite differences."""

from __future__ import annotations

import math
from functools import partial

import numpy as np
from reference_math import central_fd, random_euler, ref_dcm

from quadslam_env.models.frames import dcm_from_euler, dcm_from_euler_batch
from quadslam_env.models.lidar import (
    inverse_jacobians,
    lidar_inverse,
    lidar_jacobians,
    lidar_measure,
    measurement_residual,
)


def ref_measure(pos, dcm, lm) -> np.ndarray:
    c = dcm.T @ (np.asarray(lm) - np.asarray(pos))
    return np.array(
        [math.atan2(c[1], c[0]), math.atan2(c[2], math.hypot(c[0], c[1])), np.linalg.norm(c)]
    )


def _measure_at_pos(pos, dcm, lms):
    return lidar_measure(pos, dcm, lms)


def _measure_at_euler(eul, pos, lms):
    return lidar_measure(pos, ref_dcm(eul), lms)


def _measure_of_lm(lm, pos, dcm):
    return lidar_measure(pos, dcm, lm)


class TestLidarModel:
    def test_hand_computed_geometry(self):
        pos, dcm = np.zeros(3), np.eye(3)
        ahead = lidar_measure(pos, dcm, np.array([10.0, 0.0, 0.0]))
        np.testing.assert_allclose(ahead, [0.0, 0.0, 10.0], atol=1e-15)
        right = lidar_measure(pos, dcm, np.array([0.0, 5.0, 0.0]))
        np.testing.assert_allclose(right, [math.pi / 2, 0.0, 5.0], atol=1e-15)
        below = lidar_measure(pos, dcm, np.array([3.0, 0.0, 3.0]))  # NED: +z is down
        np.testing.assert_allclose(below, [0.0, math.pi / 4, 3 * math.sqrt(2)], atol=1e-14)
        left_up = lidar_measure(pos, dcm, np.array([0.0, -2.0, -2.0]))
        np.testing.assert_allclose(
            left_up, [-math.pi / 2, -math.pi / 4, 2 * math.sqrt(2)], atol=1e-14
        )

    def test_geometry_from_a_moved_and_rotated_vehicle(self):
        pos = np.array([1.0, 2.0, -3.0])
        # Yaw 90°: a point 10 m east of the vehicle is straight ahead.
        dcm = dcm_from_euler([0.0, 0.0, math.pi / 2])
        np.testing.assert_allclose(
            lidar_measure(pos, dcm, pos + np.array([0.0, 10.0, 0.0])), [0.0, 0.0, 10.0], atol=1e-14
        )
        # A point due north is then on the left.
        np.testing.assert_allclose(
            lidar_measure(pos, dcm, pos + np.array([4.0, 0.0, 0.0])),
            [-math.pi / 2, 0.0, 4.0],
            atol=1e-14,
        )
        # Rolled right by 30°: a horizontal point to the right appears 30° above the body plane.
        dcm = dcm_from_euler([math.radians(30), 0.0, 0.0])
        np.testing.assert_allclose(
            lidar_measure(pos, dcm, pos + np.array([0.0, 6.0, 0.0])),
            [math.pi / 2, -math.radians(30), 6.0],
            atol=1e-14,
        )

    def test_matches_reference_formula(self):
        rng = np.random.default_rng(20)
        eul = random_euler(rng, 1)[0]
        pos, dcm = rng.standard_normal(3), ref_dcm(eul)
        lms = rng.uniform(-20, 20, (30, 3))
        meas = lidar_measure(pos, dcm, lms)
        for lm, m in zip(lms, meas, strict=True):
            np.testing.assert_allclose(m, ref_measure(pos, dcm, lm), atol=1e-12)

    def test_inverse_of_measure_is_identity(self):
        rng = np.random.default_rng(21)
        eul = random_euler(rng, 1)[0]
        pos, dcm = rng.standard_normal(3), dcm_from_euler(eul)
        lms = rng.uniform(-20, 20, (40, 3))
        np.testing.assert_allclose(
            lidar_inverse(pos, dcm, lidar_measure(pos, dcm, lms)), lms, atol=1e-11
        )

    def test_broadcasting_over_particles_and_landmarks(self):
        rng = np.random.default_rng(22)
        n, k = 5, 7
        pos = rng.standard_normal((n, 1, 3))
        dcm = dcm_from_euler_batch(random_euler(rng, n))[:, None]  # (n, 1, 3, 3)
        lms = rng.uniform(-15, 15, (n, k, 3))
        meas = lidar_measure(pos, dcm, lms)
        assert meas.shape == (n, k, 3)
        for i, j in np.ndindex(n, k):
            np.testing.assert_allclose(
                meas[i, j], ref_measure(pos[i, 0], dcm[i, 0], lms[i, j]), atol=1e-12
            )
        back = lidar_inverse(pos, dcm, meas)
        assert back.shape == (n, k, 3)
        np.testing.assert_allclose(back, lms, atol=1e-11)

    def test_lidar_jacobians_vs_finite_differences(self):
        rng = np.random.default_rng(23)
        for _ in range(5):
            eul = random_euler(rng, 1, max_pitch=1.2)[0]
            pos = rng.standard_normal(3)
            dcm = dcm_from_euler(eul)
            lms = pos + dcm @ np.array([8.0, 0.0, 0.0]) + rng.uniform(-6, 6, (6, 3))
            H_pos, H_euler, H_lm = lidar_jacobians(pos, eul, dcm, lms)
            assert H_pos.shape == H_euler.shape == H_lm.shape == (6, 3, 3)
            fd_pos = central_fd(partial(_measure_at_pos, dcm=dcm, lms=lms), pos)
            fd_eul = central_fd(partial(_measure_at_euler, pos=pos, lms=lms), eul)
            fd_lm = np.stack(
                [central_fd(partial(_measure_of_lm, pos=pos, dcm=dcm), lm) for lm in lms]
            )
            for ana, num in ((H_pos, fd_pos), (H_euler, fd_eul), (H_lm, fd_lm)):
                scale = np.max(np.abs(num))
                np.testing.assert_allclose(ana, num, rtol=1e-6, atol=1e-6 * scale)

    def test_inverse_jacobians_vs_finite_differences(self):
        rng = np.random.default_rng(24)
        h = 1e-6
        for _ in range(5):
            eul = random_euler(rng, 1, max_pitch=1.2)[0]
            dcm = dcm_from_euler(eul)
            pos = rng.standard_normal(3)
            meas = np.column_stack(
                [rng.uniform(-3, 3, 6), rng.uniform(-1.2, 1.2, 6), rng.uniform(1, 30, 6)]
            )
            G_euler, G_meas = inverse_jacobians(eul, dcm, meas)
            assert G_euler.shape == G_meas.shape == (6, 3, 3)
            fd_eul = np.zeros((6, 3, 3))
            fd_meas = np.zeros((6, 3, 3))
            for i in range(3):
                d = np.zeros(3)
                d[i] = h
                fd_eul[:, :, i] = (
                    lidar_inverse(pos, ref_dcm(eul + d), meas)
                    - lidar_inverse(pos, ref_dcm(eul - d), meas)
                ) / (2 * h)
                fd_meas[:, :, i] = (
                    lidar_inverse(pos, dcm, meas + d) - lidar_inverse(pos, dcm, meas - d)
                ) / (2 * h)
            for ana, num in ((G_euler, fd_eul), (G_meas, fd_meas)):
                scale = np.max(np.abs(num))
                np.testing.assert_allclose(ana, num, rtol=1e-6, atol=1e-6 * scale)

    def test_measurement_residual_wraps_angles_not_range(self):
        measured = np.array([[math.pi - 0.01, 0.1, 10.0], [-math.pi + 0.02, -0.2, 3.0]])
        predicted = np.array([[-math.pi + 0.01, 0.1, 4.0], [math.pi - 0.03, -0.2, 3.5]])
        res = measurement_residual(measured.copy(), predicted.copy())
        np.testing.assert_allclose(res, [[-0.02, 0.0, 6.0], [0.05, 0.0, -0.5]], atol=1e-12)
