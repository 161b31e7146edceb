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

with ``∂h/∂c`` of :func:`quadslam_env.models.lidar.spherical_jacobian` (eq. 40's factor).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from quadslam_env.models.frames import wrap_pi
from quadslam_env.models.jit import kernel
from quadslam_env.models.lidar import spherical_from_body, spherical_jacobian
from quadslam_env.types import FloatArray


@kernel
def _lidar_rows(
    c: FloatArray,
    measured: FloatArray,
    dcm: FloatArray,
    e: FloatArray,
    H_pose: FloatArray,
    H_lm: FloatArray,
) -> None:
    """Fill ``e`` (k, 3), ``H_pose`` (k, 3, 6) and ``H_lm`` (k, 3, 3) of :func:`lidar_error`
    from the body vectors ``c`` (k, 3) in m, with the project's kernels of ``h`` and ``∂h/∂c``
    (:mod:`quadslam_env.models.lidar`) and the angle wrap (``[c]×`` and ``C_NBᵀ`` written out:
    one compiled loop instead of a dozen small array operations per factor call)."""
    for j in range(c.shape[0]):
        c1, c2, c3 = c[j, 0], c[j, 1], c[j, 2]
        a, b, r = spherical_from_body(c1, c2, c3)
        e[j, 0] = wrap_pi(a - measured[j, 0])
        e[j, 1] = wrap_pi(b - measured[j, 1])
        e[j, 2] = r - measured[j, 2]
        jac = spherical_jacobian(c1, c2, c3)
        for row in range(3):
            h1, h2, h3 = jac[row]
            H_pose[j, row, 0] = h2 * c3 - h3 * c2  # (∂h/∂c) [c]×
            H_pose[j, row, 1] = h3 * c1 - h1 * c3
            H_pose[j, row, 2] = h1 * c2 - h2 * c1
            H_pose[j, row, 3] = -h1
            H_pose[j, row, 4] = -h2
            H_pose[j, row, 5] = -h3
            for col in range(3):  # (∂h/∂c) C_NBᵀ
                H_lm[j, row, col] = h1 * dcm[col, 0] + h2 * dcm[col, 1] + h3 * dcm[col, 2]


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
    dcm = np.ascontiguousarray(dcm, dtype=float)
    c = (np.asarray(landmarks, dtype=float) - position) @ dcm  # rows c_i = C_NBᵀ (l_i − ρ)
    k = c.shape[0]
    e, H_pose, H_lm = np.empty((k, 3)), np.empty((k, 3, 6)), np.empty((k, 3, 3))
    _lidar_rows(c, np.asarray(measured, dtype=float), dcm, e, H_pose, H_lm)
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
    """:func:`lidar_error` of one return (the per-return factor).

    Args:
        dcm: (3, 3) ``C_NB``.
        position: (3,) ρ in N, m.
        landmark: (3,) landmark position in N, m.
        measured: (3,) the return (α rad, β rad, δ m), an array or a tuple of floats.

    Returns:
        ``(e (3,), H_pose (3, 6), H_lm (3, 3))`` as in :func:`lidar_error`.
    """
    e, H_pose, H_lm = lidar_error(
        dcm, position, np.reshape(landmark, (1, 3)), np.reshape(measured, (1, 3))
    )
    return e[0], H_pose[0], H_lm[0]


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
    diag = np.arange(k)

    def error(this: Any, values: Any, H: Any) -> FloatArray:
        keys = this.keys()
        pose = values.atPose3(keys[0])
        lms = np.array([values.atPoint3(key) for key in keys[1:]]).reshape(k, 3)
        e, H_pose, H_lm = lidar_error(pose.rotation().matrix(), pose.translation(), lms, meas)
        if H is not None:
            H[0] = H_pose.reshape(3 * k, 6)
            blocks = np.zeros((k, 3 * k, 3))  # landmark j's (3k, 3) block: rows 3j … 3j+2
            blocks.reshape(k, k, 3, 3)[diag, diag] = H_lm
            for j in range(k):
                H[j + 1] = blocks[j]
        return e.reshape(-1)

    return error
