"""Building blocks of the iSAM2 estimator's factor graph: GTSAM itself (an optional extra), the
first keyframe's priors and the IMU preintegration settings (docs/isam2.md, "How it works")."""

from __future__ import annotations

import importlib
from dataclasses import dataclass
from typing import Any

import numpy as np

from estimators.isam2.settings import (
    FIXED_BIAS_SIGMA,
    HORIZONTAL_ACCEL_VARIANCE,
    NOISE_FLOOR,
    PRIOR_VARIANCE_FLOOR,
    Isam2Settings,
)
from estimators.isam2.tangent import tangent_covariance
from quadslam_env.models.frames import dcm_from_euler
from quadslam_env.schema import ConfigError
from quadslam_env.types import EUL, GRAVITY, POS, POSE_DIM, VEL, FloatArray

GTSAM_INSTALL = "pip install 'quadslam[gtsam]'"
"""How to install the optional dependency (GTSAM 4.3)."""


def require_gtsam() -> Any:
    """Import GTSAM, or fail with the install command.

    Returns:
        The ``gtsam`` module.

    Raises:
        ConfigError: GTSAM is not installed (it is the optional extra ``quadslam[gtsam]``).
    """
    try:
        return importlib.import_module("gtsam")
    except ImportError as exc:
        raise ConfigError(
            "estimator.name: got 'isam2', which needs GTSAM (not installed: "
            f"{exc}); allowed: install the optional extra with `{GTSAM_INSTALL}`, or another "
            "estimator (ekf_slam, fastslam, fastslam_kinematic, oracle)"
        ) from exc


@dataclass
class FirstKeyframe:
    """Keyframe 0: its factors, initial values and the state they encode.

    Attributes:
        graph: ``NonlinearFactorGraph`` with the (X_0, V_0) prior and the B_0 prior.
        values: ``Values`` with X_0, V_0, B_0.
        pose: ``Pose3`` X_0. vel: (3,) V_0 in N, m/s. bias: ``imuBias.ConstantBias`` B_0.
        cov: (15, 15) prior covariance over (δθ, δt, δv_N, δb_a, δb_ω).
    """

    graph: Any
    values: Any
    pose: Any
    vel: FloatArray
    bias: Any
    cov: FloatArray


def first_keyframe(
    gtsam: Any, settings: Isam2Settings, mean0: FloatArray, cov0: FloatArray, keys: list[int]
) -> FirstKeyframe:
    """The priors of keyframe 0 at the reset's belief.

    The (9, 9) block of ``cov0`` over (ρ, v_B, Λ) is mapped to GTSAM's tangent (δθ, δt, δv_N)
    (:func:`~estimators.isam2.tangent.tangent_covariance`, eigenvalues floored at
    :data:`~estimators.isam2.settings.PRIOR_VARIANCE_FLOOR`) and enters as one whitened
    Gaussian factor on ``X_0, V_0`` with its cross-covariances; ``B_0`` has a diagonal prior
    (:meth:`~estimators.isam2.settings.Isam2Settings.bias_prior_sigmas`).

    Args:
        gtsam: The ``gtsam`` module.
        settings: The estimator's settings.
        mean0: (12,) initial mean (ρ m N, v_B m/s, Λ rad, ω rad/s).
        cov0: (12, 12) initial covariance.
        keys: ``[X_0, V_0, B_0]``.
    """
    g = gtsam
    x0, v0, b0 = keys
    euler = mean0[EUL]
    dcm = dcm_from_euler(euler)
    pose0 = g.Pose3(g.Rot3(dcm), mean0[POS].copy())
    vel0 = dcm @ mean0[VEL]
    block = cov0[:POSE_DIM, :POSE_DIM]
    sigma = tangent_covariance(
        0.5 * (block + block.T), dcm, mean0[VEL], euler, floor=PRIOR_VARIANCE_FLOOR
    )
    W = np.linalg.inv(np.linalg.cholesky(sigma))  # whitening: Wᵀ W = Σ⁻¹
    prior = g.JacobianFactor(
        x0, W[:, 0:6], v0, W[:, 6:9], np.zeros(POSE_DIM), g.noiseModel.Unit.Create(POSE_DIM)
    )
    linpoint = g.Values()
    linpoint.insert(x0, pose0)
    linpoint.insert(v0, vel0)
    graph = g.NonlinearFactorGraph()
    graph.add(g.LinearContainerFactor(prior, linpoint))
    bias_sigmas = settings.bias_prior_sigmas()
    bias0 = g.imuBias.ConstantBias()
    graph.add(g.PriorFactorConstantBias(b0, bias0, g.noiseModel.Diagonal.Sigmas(bias_sigmas)))
    values = g.Values()
    values.insert(x0, pose0)
    values.insert(v0, vel0)
    values.insert(b0, bias0)
    cov = np.zeros((15, 15))
    cov[:POSE_DIM, :POSE_DIM] = sigma
    cov[POSE_DIM:, POSE_DIM:] = np.diag(bias_sigmas**2)
    return FirstKeyframe(graph, values, pose0, vel0, bias0, cov)


def held_bias_prior(gtsam: Any, settings: Isam2Settings, key: int) -> Any | None:
    """The prior that holds a keyframe's biases at zero when they are not estimated.

    With ``estimate_imu_bias: false`` every keyframe's ``B_k`` gets a zero-mean prior of std
    :data:`~estimators.isam2.settings.FIXED_BIAS_SIGMA` (docs/isam2.md, "IMU factors"): the
    walk between keyframes alone would let the bias's variance grow over the whole flight,
    an error source the simulated IMU does not have.

    Args:
        gtsam: The ``gtsam`` module.
        settings: The estimator's settings.
        key: The keyframe's bias key.

    Returns:
        A ``PriorFactorConstantBias``, or ``None`` when the biases are estimated.
    """
    if settings.estimate_imu_bias:
        return None
    sigmas = np.full(6, FIXED_BIAS_SIGMA)
    return gtsam.PriorFactorConstantBias(
        key, gtsam.imuBias.ConstantBias(), gtsam.noiseModel.Diagonal.Sigmas(sigmas)
    )


def preintegration_params(
    gtsam: Any, settings: Isam2Settings, accel_density: float, gyro_density: float
) -> Any:
    """GTSAM preintegration settings (NED, gravity ``(0, 0, +g)``).

    Continuous densities: accelerometer ``σ_a² dt + Q_v``, gyro ``σ_ω² dt + Q_Λ``,
    integration ``integration_sigma² + Q_ρ``, bias walks squared (Forster et al. 2017,
    eq. 35–38 discretise them back with the step), each floored at
    :data:`~estimators.isam2.settings.NOISE_FLOOR`.

    Args:
        gtsam: The ``gtsam`` module.
        settings: The estimator's settings (``process_noise`` Q, integration noise, walks).
        accel_density: ``σ_a² dt`` of the samples, (m/s²)²·s.
        gyro_density: ``σ_ω² dt`` of the samples, (rad/s)²·s.

    Returns:
        A ``PreintegrationCombinedParams``.
    """
    q = np.asarray(settings.process_noise)
    p = gtsam.PreintegrationCombinedParams(np.array([0.0, 0.0, GRAVITY]))
    accel = np.full(3, accel_density)
    if settings.thrust_axis_accel:  # the horizontal specific force is taken as zero
        accel[:2] = HORIZONTAL_ACCEL_VARIANCE
    p.setAccelerometerCovariance(np.diag(np.maximum(accel + q[VEL], NOISE_FLOOR)))
    p.setGyroscopeCovariance(np.diag(np.maximum(gyro_density + q[EUL], NOISE_FLOOR)))
    p.setIntegrationCovariance(
        np.diag(np.maximum(settings.integration_sigma**2 + q[POS], NOISE_FLOOR))
    )
    walks = settings.bias_walks()
    p.setBiasAccCovariance(np.diag(walks[:3] ** 2))
    p.setBiasOmegaCovariance(np.diag(walks[3:] ** 2))
    return p


def known_map(ids: np.ndarray, positions: FloatArray) -> dict[int, FloatArray]:
    """The known map as ``{id: position (3,) m, N}``.

    Args:
        ids: (L,) landmark ids.
        positions: (L, 3) their positions in N, m.

    Raises:
        ValueError: Different numbers of ids and positions, or a non-finite position.
    """
    ids = np.asarray(ids).astype(np.int64).reshape(-1)
    pos = np.asarray(positions, dtype=float).reshape(-1, 3)
    if ids.shape[0] != pos.shape[0] or not np.isfinite(pos).all():
        raise ValueError(
            "reset: known_landmarks must be (ids (L,), finite positions (L, 3)), got "
            f"{ids.shape[0]} ids and {pos.shape[0]} positions"
        )
    return {int(i): pos[j].copy() for j, i in enumerate(ids.tolist())}


def keyframe_marginals(
    isam: Any, nav_keys: list[int], landmark_keys: list[int]
) -> tuple[FloatArray, list[FloatArray], FloatArray]:
    """A keyframe's joint marginal and each landmark's marginal, from one Bayes-tree query.

    The landmarks' marginals are the diagonal blocks of the joint marginal of the keyframe
    and every landmark: one ``jointMarginalCovariance`` costs less than one
    ``marginalCovariance`` per landmark (about 40% less with 24 landmarks in SLAM), and gives
    the same blocks to round-off (1e-13 relative).

    Args:
        isam: The ``gtsam.ISAM2`` holding the variables.
        nav_keys: The keyframe's keys ``[X_k, V_k, B_k]``.
        landmark_keys: The landmarks' keys (may be empty).

    Returns:
        ``(Σ (15, 15) over (δθ, δt, δv_N, δb_a, δb_ω), [Σ_l (3, 3) m² per landmark key],
        the whole joint (15 + 3L, 15 + 3L))``: the whole joint's rows and columns of the
        keyframe and any subset of the landmarks are that subset's joint marginal with it.
    """
    joint = np.asarray(isam.jointMarginalCovariance([*nav_keys, *landmark_keys]).fullMatrix())
    n = joint.shape[0] - 3 * len(landmark_keys)
    blocks = [
        joint[n + 3 * j : n + 3 * j + 3, n + 3 * j : n + 3 * j + 3].copy()
        for j in range(len(landmark_keys))
    ]
    return joint[:n, :n].copy(), blocks, joint


def sub_joint(joint: FloatArray, n: int, positions: list[int]) -> FloatArray:
    """The joint marginal of the keyframe and some landmarks, read off a larger one.

    Args:
        joint: (n + 3L, n + 3L) the whole joint of :func:`keyframe_marginals`.
        n: Its keyframe rows (15).
        positions: Indices into its landmark list, in the order wanted.

    Returns:
        (n + 3M, n + 3M) the joint marginal of the keyframe and those M landmarks.
    """
    rows = np.concatenate([np.arange(n), *(n + 3 * j + np.arange(3) for j in positions)])
    return joint[np.ix_(rows, rows)]
