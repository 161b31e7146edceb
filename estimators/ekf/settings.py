"""Validated settings of the EKF-SLAM estimator (``estimator.params`` in a scenario), and what
its class says from them before any lane is built (its buffers, whether it estimates the wind)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from estimators.association_settings import AssociationFields
from estimators.imu_bias_settings import ImuBiasFields
from estimators.memory import MemoryTerm, Workload, ekf_terms
from quadslam_env.models.params import VehicleParams
from quadslam_env.schema import ConfigError, spec
from quadslam_env.types import POSE_DIM, FloatArray

BIAS_DIM = 4
"""Size of the bias block b = (b_ω (3), b_az (1)) when biases are estimated with the thrust-axis
model; the whole specific force, or the wind states, add (b_ax, b_ay)
(:attr:`EkfSlamSettings.bias_dim`)."""

GYRO_BIAS, ACCEL_BIAS_Z = slice(POSE_DIM, POSE_DIM + 3), POSE_DIM + 3
"""Where b_ω (rad/s) and b_az (m/s²) sit in the filter's state ``x = (s, b, m)``: after the pose
``s = (ρ, v_B, Λ)``, whose entries sit as in the vehicle's 12-state
(:data:`~quadslam_env.types.POS`, ``VEL``, ``EUL``), but where the vehicle state has ω."""
ACCEL_BIAS_XY = slice(POSE_DIM + 4, POSE_DIM + 6)
"""Where (b_ax, b_ay) (m/s²) sit with ``specific_force: full`` or ``wind: estimate``: after
b_az, so the thrust-axis layout is the leading part of the full one."""
WIND_DIM = 2
"""The wind states (w_N, w_E) (m/s, N) of ``wind: estimate``: the last two vehicle states,
after the bias block and before the landmarks (:attr:`EkfSlamSettings.wind_slice`)."""
SPECIFIC_FORCE = ("thrust_axis", "full")
WIND_MODELS = ("none", "estimate")
WIND_WALK_MAX = 10.0
"""Largest wind random-walk density, m/s/√s: a change of 10 m/s within a second."""
WIND_SIGMA0_MAX = 50.0
"""Largest prior std of a wind state, m/s (beyond any wind a quadcopter flies in)."""

PAPER_Q_UNKNOWN = (0.2, 0.2, 0.05, 0.01, 0.01, 0.01, 0.02, 0.2, 0.2)
"""Seed 001 Table 7: diagonal of Q over (ρ, v_B, Λ) for the unknown-map case."""


@dataclass(frozen=True)
class EkfSlamSettings(ImuBiasFields, AssociationFields):
    """EKF-SLAM settings (``estimator.params`` of ``ekf_slam``), built by :meth:`from_dict`.

    Every key, its default, what it accepts and its meaning is declared below with
    :func:`~quadslam_env.schema.spec` (the docs' ``estimator.params`` table of
    ``ekf_slam`` is generated from these declarations). The bias keys come from
    :class:`~estimators.imu_bias_settings.ImuBiasFields` (b_ω (3) and b_az (1): the only IMU
    axes the model uses, λ = (ã_z, ω̃), seed 001 eq. 25) and the association keys, read with
    ``lidar.association: unknown`` (:mod:`estimators.ekf.associate`), from
    :class:`~estimators.association_settings.AssociationFields`.

    ``process_noise`` defaults to seed 001 Table 7 (unknown landmarks); Table 6 (known
    landmarks) uses ``[0.01]*6 + [0.02]*3``. ``imu_noise_in_q: false`` reproduces the paper,
    which only uses Q. ``relinearise_tolerance`` iterates an update (Gauss–Newton
    relinearisation, :mod:`estimators.ekf.correction`) after a long gap without landmarks,
    when the returning scan corrects metres; an ordinary update is far below it and is the
    first-order update bit for bit.

    ``wind: estimate`` adds the horizontal wind (w_N, w_E) as two random-walk states and the
    vehicle's drag to the thrust-axis model, with the accelerometer's horizontal axes as a
    measurement at every IMU sample (:mod:`estimators.ekf.wind`; Leishman et al. 2014).

    Known-map mode (localisation only, the paper's known-landmarks case) is not a setting: it
    is chosen per run by passing a known map at reset (the env does so when the scenario sets
    ``estimator.known_map: true``).
    """

    ONLY_FOR: ClassVar[dict[str, tuple[str, tuple[Any, ...]]]] = {
        "wind_walk": ("wind", ("estimate",)),
        "wind_sigma0": ("wind", ("estimate",)),
    }

    specific_force: str = spec(
        "thrust_axis",
        kind="str",
        choices=SPECIFIC_FORCE,
        doc="thrust_axis: the accelerometer's z axis only (seed 001 eq. 25; a horizontal "
        "specific force such as drag reads as tilt); full: all three axes, the textbook "
        "strapdown mechanisation (with estimate_imu_bias, all three accelerometer biases)",
    )
    wind: str = spec(
        "none",
        kind="str",
        choices=WIND_MODELS,
        doc="none: still air; estimate: the horizontal wind as two states, the vehicle's drag "
        "in the thrust-axis model and the horizontal accelerometer axes as its measurement "
        "(needs specific_force: thrust_axis and vehicle.drag_per_s > 0)",
    )
    wind_walk: float = spec(
        0.1,
        lo=0.0,
        hi=WIND_WALK_MAX,
        doc="random-walk density of each wind state, m/s/√s (at most 10: a gust's change "
        "within a second)",
    )
    wind_sigma0: float = spec(
        3.0,
        lo=0.0,
        lo_open=True,
        hi=WIND_SIGMA0_MAX,
        doc="prior std of each wind state about a still-air mean, m/s (> 0, at most 50)",
    )
    process_noise: tuple[float, ...] = spec(
        PAPER_Q_UNKNOWN,
        kind="vec",
        length=POSE_DIM,
        lo=0.0,
        hi=1e3,
        doc="diagonal of the continuous process-noise density Q over (ρ, v_B, Λ), m²/s, "
        "m²/s³, rad²/s, each at most 1e3 (default: seed 001 Table 7)",
    )
    imu_noise_in_q: bool = spec(
        True,
        kind="bool",
        doc="add the IMU white noise mapped through ∂f/∂λ to the discrete process noise "
        "(needed for consistency)",
    )
    relinearise_tolerance: float = spec(
        2.0,
        lo=0.0,
        lo_open=True,
        allow_inf=True,
        doc="iterate an update when the first-order update's linearisation error exceeds "
        "this many measurement noise stds on some channel; .inf: never",
    )
    max_iterations: int = spec(
        10, kind="int", lo=1, hi=100, doc="most iterations of such an update"
    )

    def validate(self) -> None:
        """The horizontal accelerometer axes are the input or the wind's measurement, not both.

        Raises:
            ConfigError: ``wind: estimate`` with ``specific_force: full``.
        """
        super().validate()
        if self.estimates_wind and self.full_specific_force:
            raise ConfigError(
                f"{self.SECTION}.wind: got 'estimate' with {self.SECTION}.specific_force "
                "'full'; allowed: wind 'none', or specific_force 'thrust_axis' (the horizontal "
                "accelerometer axes cannot be both the input and the wind's measurement)"
            )

    @property
    def full_specific_force(self) -> bool:
        """All three accelerometer axes drive the model (``specific_force: full``)."""
        return self.specific_force == "full"

    @property
    def estimates_wind(self) -> bool:
        """The horizontal wind is estimated (``wind: estimate``)."""
        return self.wind == "estimate"

    @property
    def bias_dim(self) -> int:
        """Bias states: 0 without ``estimate_imu_bias``; 4 (b_ω, b_az), or 6 (b_ω, b_az, b_ax,
        b_ay) with the whole specific force or the wind states (whose measurement reads the
        horizontal axes)."""
        if not self.estimate_imu_bias:
            return 0
        return BIAS_DIM + (2 if self.full_specific_force or self.estimates_wind else 0)

    @property
    def wind_dim(self) -> int:
        """Wind states: 2 (w_N, w_E) with ``wind: estimate``, else 0."""
        return WIND_DIM if self.estimates_wind else 0

    @property
    def wind_slice(self) -> slice:
        """Where (w_N, w_E) sit in x: the last :attr:`wind_dim` vehicle states."""
        return slice(self.nv - self.wind_dim, self.nv)

    @property
    def input_dim(self) -> int:
        """nλ, the IMU inputs of the model: 4 (a_z, ω), or 6 (a_z, ω, a_x, a_y)."""
        return 6 if self.full_specific_force else 4

    @property
    def nv(self) -> int:
        """Vehicle-state size: 9, 13 with bias states, 15 with the whole specific force's; the
        wind states add 2 (11, or 17 with the biases)."""
        return POSE_DIM + self.bias_dim + self.wind_dim

    def continuous_noise(self) -> FloatArray:
        """(nv,) diagonal of the continuous process-noise density over (s, b, w)."""
        n_accel = self.bias_dim - 3
        walks = [self.gyro_bias_walk**2] * 3 + [self.accel_bias_walk**2] * n_accel
        wind = [self.wind_walk**2] * self.wind_dim
        return np.array(list(self.process_noise) + (walks if self.estimate_imu_bias else []) + wind)

    def initial_bias_variances(self) -> FloatArray:
        """(bias_dim,) initial variances of (b_ω, b_az[, b_ax, b_ay])."""
        n_accel = self.bias_dim - 3
        return np.array([self.gyro_bias_sigma0**2] * 3 + [self.accel_bias_sigma0**2] * n_accel)

    def initial_extra_variances(self) -> FloatArray:
        """(nv − 9,) initial variances of the states after the pose: the biases, then the wind."""
        bias = self.initial_bias_variances() if self.estimate_imu_bias else np.zeros(0)
        return np.r_[bias, [self.wind_sigma0**2] * self.wind_dim]

    def drag_model(self, vehicle: Any) -> tuple[float, tuple[float, float, float]]:
        """The drag the wind states are seen through: ``vehicle``'s linear and quadratic drag.

        Args:
            vehicle: The nominal :class:`~quadslam_env.models.params.VehicleParams` the
                estimator is built with.

        Returns:
            ``(μ [1/s], c_q (3,) [1/m])``.

        Raises:
            ConfigError: No vehicle, or one without linear drag (the wind is then unobservable
                from the accelerometer).
        """
        if not isinstance(vehicle, VehicleParams) or not vehicle.drag > 0.0:
            drag = vehicle.drag if isinstance(vehicle, VehicleParams) else None
            raise ConfigError(
                f"{self.SECTION}.wind: got 'estimate' with vehicle.drag_per_s = {drag!r}; "
                "allowed: wind 'none', or a vehicle with drag_per_s > 0 (without a drag model "
                "the accelerometer does not see the wind: it is unobservable)"
            )
        q0, q1, q2 = (float(c) for c in vehicle.drag_quadratic)
        return float(vehicle.drag), (q0, q1, q2)


# ------------------------------------ what the class says from its settings before any lane


class MemorySizing:
    """Mixin of :class:`~estimators.ekf.filter.EkfSlamBatch`: the class method the env asks
    (:func:`quadslam_env.estimation.registry.memory_terms`)."""

    @classmethod
    def memory_terms(cls, load: Workload, params: dict[str, Any]) -> list[MemoryTerm]:
        """The covariance, the mean and the map's bookkeeping of ``load``'s lanes
        (:func:`estimators.memory.ekf_terms`), with the vehicle states of ``params``.

        Raises:
            ConfigError: Invalid ``estimator.params`` (as the constructor says it).
            MemoryLimitError: The covariance alone would not fit in its share.
        """
        return ekf_terms(load, EkfSlamSettings.from_dict(params).nv)


class WindStates:
    """Mixin of :class:`~estimators.ekf.filter.EkfSlamBatch`: whether its settings estimate the
    wind, asked before any filter is built
    (:func:`quadslam_env.estimation.registry.estimates_wind`)."""

    @classmethod
    def estimates_wind(cls, params: dict[str, Any]) -> bool:
        """True with ``estimator.params.wind: estimate`` (the snapshot then has ``wind``).

        Raises:
            ConfigError: Invalid ``estimator.params`` (as the constructor says it).
        """
        return EkfSlamSettings.from_dict(params).estimates_wind
