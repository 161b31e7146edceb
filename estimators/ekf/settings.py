"""Validated settings of the EKF-SLAM estimator (``estimator.params`` in a scenario)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.special import gammaincinv

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
from quadslam_env.types import POSE_DIM, FloatArray

BIAS_DIM = 4
"""Size of the bias block b = (b_ω (3), b_az (1)) when biases are estimated."""

GYRO_BIAS, ACCEL_BIAS_Z = slice(POSE_DIM, POSE_DIM + 3), POSE_DIM + 3
"""Where b_ω (rad/s) and b_az (m/s²) sit in the filter's state ``x = (s, b, m)``: after the pose
``s = (ρ, v_B, Λ)``, whose entries sit as in the vehicle's 12-state
(:data:`~quadslam_env.types.POS`, ``VEL``, ``EUL``), but where the vehicle state has ω."""

PAPER_Q_UNKNOWN = (0.2, 0.2, 0.05, 0.01, 0.01, 0.01, 0.02, 0.2, 0.2)
"""Seed 001 Table 7: diagonal of Q over (ρ, v_B, Λ) for the unknown-map case."""

_TYPES: dict[str, type | tuple[type, ...]] = {
    "process_noise": (list, tuple, np.ndarray),
    **IMU_BIAS_TYPES,
    **ASSOCIATION_TYPES,
    "imu_noise_in_q": bool,
    "relinearise_tolerance": (float, int),
    "max_iterations": int,
}


@dataclass(frozen=True)
class EkfSlamSettings:
    """EKF-SLAM settings, built from ``estimator.params`` by :meth:`from_params`.

    The accepted keys (all optional):

    ``process_noise`` (list of 9 floats ≥ 0, default seed 001 Table 7
    ``[0.2, 0.2, 0.05, 0.01, 0.01, 0.01, 0.02, 0.2, 0.2]``): diagonal of the continuous-time
    process-noise spectral density Q over (ρ, v_B, Λ), in m²/s, m²/s³, rad²/s. Table 6
    (known landmarks) uses ``[0.01]*6 + [0.02]*3``.

    ``estimate_imu_bias`` (bool, default False): augment the state with the gyro bias b_ω (3)
    and the accelerometer z bias b_az (1); these are the only IMU axes the model uses
    (λ = (ã_z, ω̃), seed 001 eq. 25). Random walks with the settings below.

    ``gyro_bias_sigma0`` (float ≥ 0, default 0.01 rad/s): initial bias std per axis.

    ``accel_bias_sigma0`` (float ≥ 0, default 0.05 m/s²): initial z-bias std.

    ``gyro_bias_walk`` (float ≥ 0, default 1e-4 rad/s/√s): random-walk density.

    ``accel_bias_walk`` (float ≥ 0, default 1e-3 m/s²/√s): random-walk density.

    ``gate_probability`` (float in (0, 1], default 0.99): per-landmark χ² gate (3 DOF;
    0.99 → NIS threshold 11.345). 1.0 disables gating.

    ``imu_noise_in_q`` (bool, default True): add the IMU white noise mapped through ``∂f/∂λ``
    to the discrete process noise (needed for consistency; False reproduces the paper, which
    only uses Q).

    With ``lidar.association: unknown`` (unlabeled returns, :mod:`estimators.ekf.associate`):

    ``association`` (``nn`` | ``jcbb``, default ``jcbb``): nearest neighbour or joint
    compatibility branch and bound, both gated at ``gate_probability``
    (:mod:`estimators.association`).

    ``new_landmark_probability`` (float ≥ gate_probability and < 1, default 0.9999 or
    gate_probability if larger): a return starts a new landmark only when it is outside this
    χ²₃ gate of every landmark; a return between the two gates is dropped (so a true
    landmark's rare return outside the association gate does not start a duplicate of it).

    ``confirm_hits`` (int in [1, 1000], default 3): a return that gates with no map landmark
    starts a tentative landmark, which enters the map once it has been observed in
    ``confirm_hits`` of its first ``confirm_window`` scans and is dropped otherwise
    (:mod:`estimators.tentative`).

    ``confirm_window`` (int in [confirm_hits, 1000], default 5): the scans a tentative
    landmark has to reach ``confirm_hits``.

    ``relinearise_tolerance`` (float > 0, default 2.0; ``.inf`` turns it off): iterate an
    update (Gauss–Newton relinearisation, :mod:`estimators.ekf.correction`) when the
    first-order update's linearisation error exceeds this many measurement noise stds on some
    channel — after a long gap without landmarks, when the returning scan corrects metres. An
    ordinary update is far below it and is the first-order update bit for bit.

    ``max_iterations`` (int in [1, 100], default 10): most iterations of such an update.

    Known-map mode (localisation only, the paper's known-landmarks case) is not a setting: it
    is chosen per run by passing a known map at reset (the env does so when the scenario sets
    ``estimator.known_map: true``).
    """

    process_noise: tuple[float, ...] = PAPER_Q_UNKNOWN
    estimate_imu_bias: bool = IMU_BIAS_DEFAULTS["estimate_imu_bias"]
    gyro_bias_sigma0: float = IMU_BIAS_DEFAULTS["gyro_bias_sigma0"]
    accel_bias_sigma0: float = IMU_BIAS_DEFAULTS["accel_bias_sigma0"]
    gyro_bias_walk: float = IMU_BIAS_DEFAULTS["gyro_bias_walk"]
    accel_bias_walk: float = IMU_BIAS_DEFAULTS["accel_bias_walk"]
    gate_probability: float = ASSOCIATION_DEFAULTS["gate_probability"]
    imu_noise_in_q: bool = True
    association: str = ASSOCIATION_DEFAULTS["association"]
    confirm_hits: int = ASSOCIATION_DEFAULTS["confirm_hits"]
    confirm_window: int = ASSOCIATION_DEFAULTS["confirm_window"]
    new_landmark_probability: float = ASSOCIATION_DEFAULTS["new_landmark_probability"]
    relinearise_tolerance: float = 2.0
    max_iterations: int = 10

    @classmethod
    def from_params(cls, params: dict[str, Any]) -> EkfSlamSettings:
        """Validate ``estimator.params``.

        Raises:
            ValueError: Unknown key, wrong type or out-of-range value (the message names the
                key, the value and what is allowed).
        """
        check_kwargs("estimator.params", params, _TYPES)
        q = params.get("process_noise", PAPER_Q_UNKNOWN)
        if len(q) != POSE_DIM or not all(
            isinstance(e, float | int) and not isinstance(e, bool) for e in q
        ):
            raise ValueError(
                f"estimator.params.process_noise: got {q!r}; allowed: a list of 9 numbers >= 0"
            )
        association = association_settings(params)
        tol = float(params.get("relinearise_tolerance", 2.0))
        if not tol > 0.0:
            raise ValueError(
                f"estimator.params.relinearise_tolerance: got {tol!r}; allowed: a number > 0 "
                "(.inf: no iteration)"
            )
        iters = params.get("max_iterations", 10)
        if not 1 <= iters <= 100:
            raise ValueError(
                f"estimator.params.max_iterations: got {iters!r}; allowed: an integer in [1, 100]"
            )
        return cls(
            relinearise_tolerance=tol,
            max_iterations=int(iters),
            **association,
            process_noise=tuple(check_nonneg("process_noise", e) for e in q),
            **imu_bias_settings(params),
            imu_noise_in_q=bool(params.get("imu_noise_in_q", True)),
        )

    @property
    def nv(self) -> int:
        """Vehicle-state size: 9, or 13 with bias states."""
        return POSE_DIM + (BIAS_DIM if self.estimate_imu_bias else 0)

    @property
    def gate_threshold(self) -> float:
        """Per-landmark 3-DOF NIS threshold (χ² quantile; inf when gating is off)."""
        if self.gate_probability >= 1.0:
            return math.inf
        return float(2.0 * gammaincinv(1.5, self.gate_probability))

    def continuous_noise(self) -> FloatArray:
        """(nv,) diagonal of the continuous process-noise density over (s, b)."""
        walks = [self.gyro_bias_walk**2] * 3 + [self.accel_bias_walk**2]
        return np.array(list(self.process_noise) + (walks if self.estimate_imu_bias else []))

    def initial_bias_variances(self) -> FloatArray:
        """(4,) initial variances of (b_ω, b_az)."""
        return np.array([self.gyro_bias_sigma0**2] * 3 + [self.accel_bias_sigma0**2])
