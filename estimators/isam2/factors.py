"""LiDAR landmark factors for GTSAM: the range–azimuth–elevation model with analytic Jacobians.

The measurement of landmark ``l`` (N, m) from the pose ``(C_NB, ρ)`` is seed 001 eq. 30–31
(azimuth corrected, :mod:`quadslam_env.models.lidar`)::

    c = C_NBᵀ (l − ρ),   y = h(c) = (atan2(c2, c1), atan2(c3, ‖c_12‖), ‖c‖)   (α, β rad; δ m)

and the factor's error is ``e = h(c) − y_measured`` with the two angle differences wrapped to
(−π, π], whitened by the LiDAR's own ``(σ_α, σ_β, σ_δ)``: so the factor is exactly the
likelihood the EKF linearises (GTSAM's ``BearingRangeFactor3D`` measures the bearing as a unit
vector on S², whose noise does not map onto azimuth and elevation stds).

Jacobians with respect to GTSAM's ``Pose3`` tangent ``(δθ, δt)`` (body frame,
:mod:`estimators.isam2.tangent`) and the landmark ``Point3``: with ``C_NB ← C_NB Exp(δθ)`` and
``ρ ← ρ + C_NB δt``, ``c ← c + [c]× δθ − δt`` to first order, so

    ∂e/∂δθ = (∂h/∂c) [c]×,    ∂e/∂δt = −∂h/∂c,    ∂e/∂l = (∂h/∂c) C_NBᵀ,

with ``∂h/∂c`` of :func:`quadslam_env.models.lidar.measure_jacobian_body` (eq. 40's factor).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np

from quadslam_env.models.frames import wrap_angle
from quadslam_env.models.lidar import measure_from_body, measure_jacobian_body
from quadslam_env.types import FloatArray


def _skew_rows(c: FloatArray) -> FloatArray:
    """(k, 3, 3) cross-product matrices ``[c_i]×`` of the rows of ``c`` (k, 3)."""
    k = c.shape[0]
    S = np.zeros((k, 3, 3))
    S[:, 0, 1], S[:, 0, 2] = -c[:, 2], c[:, 1]
    S[:, 1, 0], S[:, 1, 2] = c[:, 2], -c[:, 0]
    S[:, 2, 0], S[:, 2, 1] = -c[:, 1], c[:, 0]
    return S


def lidar_error(
    dcm: FloatArray, position: FloatArray, landmarks: FloatArray, measured: FloatArray
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Error of k LiDAR returns and its Jacobians (module docstring; seed 001 eq. 30–31, 40).

    Args:
        dcm: (3, 3) ``C_NB`` of the keyframe pose.
        position: (3,) ρ in N, m.
        landmarks: (k, 3) landmark positions in N, m.
        measured: (k, 3) returns (α rad, β rad, δ m).

    Returns:
        ``(e, H_pose, H_lm)``: e (k, 3) ``h − y`` with wrapped angles (rad, rad, m);
        ``H_pose`` (k, 3, 6) over GTSAM's Pose3 tangent (δθ rad, δt m, both in B);
        ``H_lm`` (k, 3, 3) over the landmark position (m).
    """
    c = (landmarks - position) @ dcm  # rows c_i = C_NBᵀ (l_i − ρ)
    e = measure_from_body(c) - measured
    e[:, :2] = wrap_angle(e[:, :2])
    Hc = measure_jacobian_body(c)
    H_pose = np.empty((c.shape[0], 3, 6))
    H_pose[:, :, 0:3] = Hc @ _skew_rows(c)
    H_pose[:, :, 3:6] = -Hc
    H_lm = Hc @ dcm.T
    return e, H_pose, H_lm


ErrorFunction = Callable[[Any, Any, Any], FloatArray]
"""``f(this: gtsam.CustomFactor, values: gtsam.Values, H: gtsam.JacobianVector | None)``."""


def known_map_error(landmarks: FloatArray, measured: FloatArray) -> ErrorFunction:
    """Error function of one scan of a known map: one factor on the keyframe pose alone.

    The landmarks are constants (the map is known exactly), so the factor has one key (the
    pose) and the stacked error ``(3k,)``.

    Args:
        landmarks: (k, 3) known positions of the returned landmarks in N, m.
        measured: (k, 3) their returns (α rad, β rad, δ m).
    """
    lms = np.array(landmarks, dtype=float)
    meas = np.array(measured, dtype=float)

    def error(this: Any, values: Any, H: Any) -> FloatArray:
        pose = values.atPose3(this.keys()[0])
        e, H_pose, _ = lidar_error(pose.rotation().matrix(), pose.translation(), lms, meas)
        if H is not None:
            H[0] = H_pose.reshape(-1, 6)
        return e.reshape(-1)

    return error


def lidar_error_one(
    dcm: FloatArray,
    position: FloatArray,
    landmark: FloatArray,
    measured: FloatArray | tuple[float, ...],
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """:func:`lidar_error` of one return, in scalar arithmetic (the factor's hot path).

    Args:
        dcm: (3, 3) ``C_NB``.
        position: (3,) ρ in N, m.
        landmark: (3,) landmark position in N, m.
        measured: (3,) the return (α rad, β rad, δ m), an array or a tuple of floats.

    Returns:
        ``(e (3,), H_pose (3, 6), H_lm (3, 3))`` as in :func:`lidar_error`.
    """
    c1, c2, c3 = ((np.asarray(landmark) - position) @ dcm).tolist()
    a, b, r = measured.tolist() if isinstance(measured, np.ndarray) else measured
    h2 = max(c1 * c1 + c2 * c2, 1e-12)  # floored as spherical_jacobian (α undefined overhead)
    h = math.sqrt(h2)
    d2 = h2 + c3 * c3
    d = math.sqrt(d2)
    e = np.array(
        [
            _wrap(math.atan2(c2, c1) - a),
            _wrap(math.atan2(c3, math.hypot(c1, c2)) - b),
            math.sqrt(c1 * c1 + c2 * c2 + c3 * c3) - r,
        ]
    )
    dh = d2 * h
    Hc = np.array(
        [
            [-c2 / h2, c1 / h2, 0.0],
            [-c1 * c3 / dh, -c2 * c3 / dh, h / d2],
            [c1 / d, c2 / d, c3 / d],
        ]
    )
    skew_c = np.array([[0.0, -c3, c2], [c3, 0.0, -c1], [-c2, c1, 0.0]])
    H_pose = np.hstack((Hc @ skew_c, -Hc))
    return e, H_pose, Hc @ dcm.T


def _wrap(angle: float) -> float:
    """``angle`` wrapped to (−π, π] (scalar :func:`~quadslam_env.models.frames.wrap_angle`)."""
    wrapped = math.remainder(angle, 2.0 * math.pi)
    return math.pi if wrapped == -math.pi else wrapped


def landmark_error(measured: FloatArray) -> ErrorFunction:
    """Error function of one return of a mapped landmark: keys (pose, landmark), error (3,).

    Args:
        measured: (3,) the return (α rad, β rad, δ m).
    """
    meas = tuple(float(v) for v in np.asarray(measured, dtype=float).reshape(3))

    def error(this: Any, values: Any, H: Any) -> FloatArray:
        keys = this.keys()
        pose = values.atPose3(keys[0])
        e, H_pose, H_lm = lidar_error_one(
            pose.rotation().matrix(), pose.translation(), values.atPoint3(keys[1]), meas
        )
        if H is not None:
            H[0] = H_pose
            H[1] = H_lm
        return e

    return error


def scan_error(measured: FloatArray) -> ErrorFunction:
    """Error function of one scan of mapped landmarks: keys (pose, l_1 … l_k), error (3k,).

    One factor per scan instead of one per return: the same likelihood (the returns' noises
    are independent, so the stacked whitened error is the per-return ones side by side), with
    one Python call per linearisation instead of k. Return j's rows depend on the pose and
    on ``l_j`` only.

    Args:
        measured: (k, 3) the returns (α rad, β rad, δ m), in the order of the landmark keys.
    """
    meas = np.array(measured, dtype=float).reshape(-1, 3)
    k = meas.shape[0]

    def error(this: Any, values: Any, H: Any) -> FloatArray:
        keys = this.keys()
        pose = values.atPose3(keys[0])
        lms = np.array([values.atPoint3(key) for key in keys[1:]]).reshape(k, 3)
        e, H_pose, H_lm = lidar_error(pose.rotation().matrix(), pose.translation(), lms, meas)
        if H is not None:
            H[0] = H_pose.reshape(3 * k, 6)
            for j in range(k):
                block = np.zeros((3 * k, 3))
                block[3 * j : 3 * j + 3] = H_lm[j]
                H[j + 1] = block
        return e.reshape(-1)

    return error
