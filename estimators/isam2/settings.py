"""Validated settings of the iSAM2 estimator (``estimator.params`` with ``estimator.name: isam2``).

The keys shared with EKF-SLAM (``process_noise``, ``estimate_imu_bias`` and the four bias keys;
the five data-association keys) have the EKF's meaning, units and defaults
(:class:`estimators.ekf.settings.EkfSlamSettings`, :mod:`estimators.association_settings`), so a
scenario written for the EKF keeps its IMU model and its association rule when its estimator is
swapped; the EKF's own iteration keys (``imu_noise_in_q``, ``relinearise_tolerance``,
``max_iterations``) are rejected with the list of accepted keys.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from estimators.association import chi2_threshold
from estimators.association_settings import (
    ASSOCIATION_DEFAULTS,
    ASSOCIATION_TYPES,
    association_settings,
)
from estimators.imu_bias_settings import (
    IMU_BIAS_DEFAULTS,
    IMU_BIAS_TYPES,
    check_nonneg,
    imu_bias_settings,
)
from estimators.settings_check import check_kwargs
from quadslam_env.types import POSE_DIM

_TYPES: dict[str, type | tuple[type, ...]] = {
    "window_s": (float, int, type(None)),
    "process_noise": (list, tuple, np.ndarray),
    **IMU_BIAS_TYPES,
    "integration_sigma": (float, int),
    "relinearize_threshold": (float, int),
    "relinearize_skip": int,
    "factorization": str,
    "iterations": int,
    "landmark_covariances": bool,
    "factor_per_return": bool,
    **ASSOCIATION_TYPES,
}

FIXED_BIAS_SIGMA = 1e-5
"""With ``estimate_imu_bias: false`` the biases are held at zero by a prior of this std on
*every* keyframe's bias and a random walk of this density between keyframes (m/s² and
m/s²/√s for the accelerometer, rad/s and rad/s/√s for the gyro): the IMU factor of Forster
et al. (2017) always carries bias variables, and a zero-variance prior would make the
information matrix singular. The prior at every keyframe keeps the bias's variance below
this std squared for the whole flight; a prior on the first keyframe alone would let the walk
grow it as ``σ² (1 + t)`` — 7e-5 rad/s after 50 s — and the reported covariance would carry a
bias the simulated IMU does not have (on ``paper_ekf_figure8_known`` it made the attitude's
variance 25% larger; docs/isam2.md, "Consistency"). Over one 0.1 s keyframe interval a bias
of this std moves the attitude by 1e-6 rad and the position by 5e-8 m, far below the
sensors' noise."""

NOISE_FLOOR = 1e-12
"""Smallest continuous-time variance (per axis) handed to GTSAM's preintegration (an ideal
IMU has zero noise density, which would make the IMU factor's covariance singular)."""

PRIOR_VARIANCE_FLOOR = 1e-8
"""Smallest eigenvalue of the initial prior's covariance in GTSAM's tangent space (rad², m²,
m²/s²): the scenarios' ``estimator.initial_cov_diag`` may hold zeros (a known attitude),
which a Gaussian factor cannot represent."""


def _check_positive(key: str, value: Any) -> float:
    value = float(value)
    if not (math.isfinite(value) and value > 0.0):
        raise ValueError(f"estimator.params.{key}: got {value!r}; allowed: a finite number > 0")
    return value


FACTORIZATIONS = ("qr", "cholesky")


def _check_choice(key: str, value: str, allowed: tuple[str, ...]) -> str:
    if value not in allowed:
        raise ValueError(f"estimator.params.{key}: got {value!r}; allowed: one of {allowed}")
    return value


def _check_int(key: str, value: int, lo: int, hi: int) -> int:
    if not lo <= value <= hi:
        raise ValueError(
            f"estimator.params.{key}: got {value!r}; allowed: an integer in [{lo}, {hi}]"
        )
    return int(value)


@dataclass(frozen=True)
class Isam2Settings:
    """iSAM2 settings, built from ``estimator.params`` by :meth:`from_params`.

    The accepted keys (all optional):

    ``window_s`` (float > 0 or null, default 3.0): smoother lag in s. Vehicle states (pose,
    velocity, biases) older than this are marginalised (GTSAM's
    ``IncrementalFixedLagSmoother``), so the cost per scan stays bounded; landmarks stay in
    the window for the whole episode (their timestamps are refreshed at every keyframe, so a
    landmark that comes back into view still has its variable). ``null`` keeps every state:
    full iSAM2 (Kaess et al. 2012), whose cost grows with the episode.

    ``process_noise`` (list of 9 floats ≥ 0, default all 0): the EKF's continuous process
    noise Q over (ρ, v_B, Λ) in m²/s, m²/s³, rad²/s, added to the preintegration's inputs:
    the ρ block to the integration covariance, the v_B block to the accelerometer's and the
    Λ block to the gyro's (exact for isotropic blocks in level flight). The simulator has no
    process noise beyond the IMU's, so the default is none.

    ``estimate_imu_bias`` (bool, default False): estimate the six IMU biases (accelerometer
    m/s², gyro rad/s) as a random walk between keyframes (GTSAM's ``CombinedImuFactor``).
    Off: the biases are held at zero (:data:`FIXED_BIAS_SIGMA`, a prior at every keyframe).

    ``gyro_bias_sigma0`` (float ≥ 0, default 0.01 rad/s), ``accel_bias_sigma0`` (float ≥ 0,
    default 0.05 m/s²): prior std per axis of the biases at the first keyframe (as the EKF's).

    ``gyro_bias_walk`` (float ≥ 0, default 1e-4 rad/s/√s), ``accel_bias_walk`` (float ≥ 0,
    default 1e-3 m/s²/√s): random-walk densities of the biases (as the EKF's).

    ``integration_sigma`` (float ≥ 0, default 1e-4 m/√s): GTSAM's integration noise, the
    position error of integrating a held IMU sample (added to the ρ block of ``process_noise``).

    ``relinearize_threshold`` (float > 0, default 0.01): iSAM2 relinearises a variable when
    its tangent-space update exceeds this (rad, m, m/s).

    ``relinearize_skip`` (int in [1, 100], default 1): check for relinearisation every this
    many updates.

    ``factorization`` (``qr`` | ``cholesky``, default ``qr``): how iSAM2 eliminates the
    linearised system. Cholesky squares the condition number: after ~15 s of dead reckoning
    (the map out of view) the position's variance is ~1e8 times the held biases' and it
    reports an indeterminate system; QR works on the square-root information directly
    (same solution, ~15% more time per scan).

    ``iterations`` (int in [1, 20], default 1): iSAM2 updates per keyframe (the later ones
    without new factors: one more Gauss–Newton step each).

    ``landmark_covariances`` (bool, default True): recover every mapped landmark's marginal
    covariance at each keyframe (for ``BatchEstimate.landmark_covs``); off, they are reported as
    zero, which saves one marginal per landmark and keyframe.

    ``factor_per_return`` (bool, default False): unknown map, one LiDAR factor per return
    (keys pose, landmark) instead of one per scan (keys pose and the scan's landmarks). The
    two are the same likelihood; per scan makes one Python call per scan and linearisation
    instead of one per return.

    With ``lidar.association: unknown`` (unlabeled returns, :mod:`estimators.isam2.associate`),
    EKF-SLAM's keys with EKF-SLAM's meaning and defaults (:mod:`estimators.association_settings`):

    ``association`` (``nn`` | ``jcbb``, default ``jcbb``): nearest neighbour or joint
    compatibility branch and bound (:mod:`estimators.association`) on the smoother's joint
    marginal of the scan's pose and the landmarks in the gate.

    ``gate_probability`` (float in (0, 1], default 0.99): the χ²₃ gate of a (return, landmark)
    pair on its Mahalanobis distance (0.99 → 11.345); 1.0 disables gating.

    ``new_landmark_probability`` (float ≥ gate_probability and < 1, default 0.9999 or
    gate_probability if larger): a return starts a tentative landmark only when it is outside
    this χ²₃ gate of every landmark; one between the two gates is dropped.

    ``confirm_hits`` (int in [1, 1000], default 3), ``confirm_window`` (int in
    [confirm_hits, 1000], default 5): a tentative landmark enters the graph once it has been
    seen in ``confirm_hits`` of its first ``confirm_window`` scans, with a factor for every
    sighting whose keyframe is still in the smoother (:mod:`estimators.tentative`).

    The measurement noise (LiDAR σ per return, IMU white noise per sample) comes with the
    data, as for the EKF (:class:`~quadslam_env.measurements.LidarScan`,
    :class:`~quadslam_env.measurements.ImuSample`).
    """

    window_s: float | None = 3.0
    process_noise: tuple[float, ...] = (0.0,) * POSE_DIM
    estimate_imu_bias: bool = IMU_BIAS_DEFAULTS["estimate_imu_bias"]
    gyro_bias_sigma0: float = IMU_BIAS_DEFAULTS["gyro_bias_sigma0"]
    accel_bias_sigma0: float = IMU_BIAS_DEFAULTS["accel_bias_sigma0"]
    gyro_bias_walk: float = IMU_BIAS_DEFAULTS["gyro_bias_walk"]
    accel_bias_walk: float = IMU_BIAS_DEFAULTS["accel_bias_walk"]
    integration_sigma: float = 1e-4
    relinearize_threshold: float = 0.01
    relinearize_skip: int = 1
    factorization: str = "qr"
    iterations: int = 1
    landmark_covariances: bool = True
    factor_per_return: bool = False
    association: str = ASSOCIATION_DEFAULTS["association"]
    gate_probability: float = ASSOCIATION_DEFAULTS["gate_probability"]
    new_landmark_probability: float = ASSOCIATION_DEFAULTS["new_landmark_probability"]
    confirm_hits: int = ASSOCIATION_DEFAULTS["confirm_hits"]
    confirm_window: int = ASSOCIATION_DEFAULTS["confirm_window"]

    @classmethod
    def from_params(cls, params: dict[str, Any]) -> Isam2Settings:
        """Validate ``estimator.params``.

        Raises:
            ValueError: Unknown key, wrong type or out-of-range value (the message names the
                key, the value and what is allowed).
        """
        check_kwargs("estimator.params", params, _TYPES)
        default = cls()

        def get(key: str) -> Any:  # the dataclass field's default when the key is absent
            return params.get(key, getattr(default, key))

        window = get("window_s")
        if window is not None:
            window = _check_positive("window_s", window)
        q = get("process_noise")
        if len(q) != POSE_DIM or not all(
            isinstance(e, float | int | np.floating | np.integer) and not isinstance(e, bool)
            for e in q
        ):
            raise ValueError(
                f"estimator.params.process_noise: got {q!r}; allowed: a list of 9 numbers >= 0"
            )
        return cls(
            window_s=window,
            process_noise=tuple(check_nonneg("process_noise", e) for e in q),
            **imu_bias_settings(params),
            integration_sigma=check_nonneg("integration_sigma", get("integration_sigma")),
            relinearize_threshold=_check_positive(
                "relinearize_threshold", get("relinearize_threshold")
            ),
            relinearize_skip=_check_int("relinearize_skip", get("relinearize_skip"), 1, 100),
            factorization=_check_choice("factorization", get("factorization"), FACTORIZATIONS),
            iterations=_check_int("iterations", get("iterations"), 1, 20),
            landmark_covariances=bool(get("landmark_covariances")),
            factor_per_return=bool(get("factor_per_return")),
            **association_settings(params),
        )

    @property
    def gate(self) -> float:
        """The association gate ``χ²₃(gate_probability)`` on a pair's NIS (inf when p = 1)."""
        return chi2_threshold(3, self.gate_probability)

    @property
    def new_gate(self) -> float:
        """The new-landmark gate ``χ²₃(new_landmark_probability)`` (≥ :attr:`gate` unless the
        association gate is off)."""
        return chi2_threshold(3, self.new_landmark_probability)

    def bias_prior_sigmas(self) -> tuple[float, float]:
        """Prior std per axis of (accelerometer m/s², gyro rad/s) biases at the first keyframe
        (at least :data:`FIXED_BIAS_SIGMA`: a zero std is a singular factor)."""
        if not self.estimate_imu_bias:
            return FIXED_BIAS_SIGMA, FIXED_BIAS_SIGMA
        return (
            max(self.accel_bias_sigma0, FIXED_BIAS_SIGMA),
            max(self.gyro_bias_sigma0, FIXED_BIAS_SIGMA),
        )

    def bias_walks(self) -> tuple[float, float]:
        """Random-walk densities of (accelerometer m/s²/√s, gyro rad/s/√s) biases (at least
        :data:`FIXED_BIAS_SIGMA`)."""
        if not self.estimate_imu_bias:
            return FIXED_BIAS_SIGMA, FIXED_BIAS_SIGMA
        return (
            max(self.accel_bias_walk, FIXED_BIAS_SIGMA),
            max(self.gyro_bias_walk, FIXED_BIAS_SIGMA),
        )
