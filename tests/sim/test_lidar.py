"""The LiDAR kernels of :mod:`quadslam_env.models.lidar` over leading axes (seed 001 eq. 31–50).

tests/sim/test_models.py checks the one-pose functions against reference formulas and finite
differences; here the gufunc Jacobians are checked by finite differences with batch axes
(N particles × k landmarks, as FastSLAM calls them), and the per-landmark kernels the EKF calls
against the NumPy-facing functions.
"""

from __future__ import annotations

import numpy as np
import pytest

from quadslam_env.models.frames import dcm_and_partials, dcm_from_euler_batch, wrap_angle
from quadslam_env.models.lidar import (
    body_from_measure,
    body_vector,
    inverse_jacobians,
    lidar_inverse,
    lidar_inverse_model,
    lidar_jacobians,
    lidar_measure,
    lidar_measure_jacobian,
    lidar_model,
    measure_from_body,
    measure_inverse_jacobian,
    measure_jacobian_body,
)

H_FD = 1e-6


def _fd(fun, x: np.ndarray) -> np.ndarray:
    """Central differences of ``fun`` ((..., 3) → (..., 3)) at each row of x (..., 3), all
    three steps in one call; angle channels are wrapped. Returns (..., 3, 3) = ∂fun/∂x."""
    steps = H_FD * np.eye(3)  # row i steps x_i
    diff = fun(x[..., None, :] + steps) - fun(x[..., None, :] - steps)  # (..., i, out)
    diff[..., :2] = wrap_angle(diff[..., :2])
    return np.swapaxes(diff, -1, -2) / (2 * H_FD)


def _close(ana: np.ndarray, num: np.ndarray) -> None:
    np.testing.assert_allclose(ana, num, rtol=1e-6, atol=1e-6 * np.max(np.abs(num)))


def _particles(n: int = 6, k: int = 5, seed: int = 0):
    rng = np.random.default_rng(seed)
    euler = rng.uniform(-1.2, 1.2, (n, 3))
    pos = rng.normal(0.0, 2.0, (n, 1, 3))
    lms = pos + rng.uniform(3.0, 15.0, (n, k, 3)) * rng.choice([-1.0, 1.0], (n, k, 3))
    return euler, pos, dcm_from_euler_batch(euler)[:, None], lms


def test_batched_forward_jacobians_match_finite_differences() -> None:
    _, pos, dcm, lms = _particles()
    h, H_lm = lidar_measure_jacobian(pos, dcm, lms)
    assert h.shape == (6, 5, 3) and H_lm.shape == (6, 5, 3, 3)
    np.testing.assert_array_equal(h, lidar_measure(pos, dcm, lms))
    _close(H_lm, _fd(lambda lm: lidar_measure(pos[..., None, :], dcm[..., None, :, :], lm), lms))
    c = body_vector(pos, dcm, lms)
    np.testing.assert_array_equal(measure_from_body(c), h)
    _close(measure_jacobian_body(c), _fd(measure_from_body, c))


def test_batched_inverse_jacobian_matches_finite_differences() -> None:
    rng = np.random.default_rng(1)
    y = np.stack(
        [rng.uniform(-3, 3, (4, 7)), rng.uniform(-1.4, 1.4, (4, 7)), rng.uniform(0.5, 30, (4, 7))],
        axis=-1,
    )
    D = measure_inverse_jacobian(y)
    assert D.shape == (4, 7, 3, 3)
    _close(D, _fd(body_from_measure, y))
    np.testing.assert_allclose(measure_from_body(body_from_measure(y)), y, rtol=0, atol=1e-12)


def test_per_landmark_kernels_equal_the_numpy_functions() -> None:
    euler, pos, dcm, lms = _particles(n=3, k=4, seed=2)
    for b in range(3):
        C, dC = np.empty((3, 3)), np.empty((3, 3, 3))
        dcm_and_partials(*euler[b], C, dC)
        np.testing.assert_array_equal(C, dcm[b, 0])
        H_pos, H_eul, H_lm = lidar_jacobians(pos[b, 0], euler[b], C, lms[b])
        meas = lidar_measure(pos[b, 0], C, lms[b])
        G_eul, G_y = inverse_jacobians(euler[b], C, meas)
        for i in range(4):
            h, H = np.empty(3), np.empty((3, 9))
            lidar_model(pos[b, 0], C, dC, lms[b, i], h, H)
            np.testing.assert_array_equal(h, meas[i])
            np.testing.assert_array_equal(H, np.hstack([H_pos[i], H_eul[i], H_lm[i]]))
            lm, ge, gy = np.empty(3), np.empty((3, 3)), np.empty((3, 3))
            lidar_inverse_model(pos[b, 0], C, dC, meas[i], lm, ge, gy)
            np.testing.assert_array_equal(lm, lidar_inverse(pos[b, 0], C, meas[i]))
            np.testing.assert_array_equal(ge, G_eul[i])
            np.testing.assert_array_equal(gy, G_y[i])


@pytest.mark.parametrize("fun", [measure_from_body, measure_jacobian_body, body_from_measure])
def test_rejects_vectors_that_are_not_3d(fun) -> None:
    with pytest.raises(ValueError, match=r"\(\.\.\., 3\)"):
        fun(np.zeros((4, 2)))
