"""Validated settings of the FastSLAM filters (``estimator.params`` of ``fastslam`` and
``fastslam_kinematic``).

Every key, its default, what it accepts and its meaning is declared here with
:func:`~quadslam_env.schema.spec`; the docs' ``estimator.params`` tables are generated
from these declarations. :class:`FastSlamSettings` holds the keys both filters read (the gate
and the M-of-N rule from :class:`~estimators.association_settings.GatedFields`);
:class:`DynamicFastSlamSettings` and :class:`KinematicFastSlamSettings` add each filter's own
keys and defaults (the robustness tuning behind the defaults is in
:class:`~estimators.fastslam.dynamic.DynamicFastSLAM`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from estimators.association import chi2_threshold
from estimators.association_settings import GatedFields
from estimators.imu_bias_settings import ACCEL_BIAS_MAX, GYRO_BIAS_MAX
from quadslam_env.schema import spec
from quadslam_env.types import MEAS_DIM, STATE_DIM, FloatArray

SIGMA_FLOOR = 1e-9
"""Smallest sensor standard deviation used in R (keeps S invertible for noise-free sensors)."""


def scan_noise(sigma: FloatArray) -> FloatArray:
    """The LiDAR noise covariance R (3, 3) of a scan's σ (3,) (rad, rad, m), floored."""
    sig = np.maximum(np.asarray(sigma, dtype=float).reshape(3), SIGMA_FLOOR)
    return np.diag(sig * sig)


def _noise_spec(default: tuple[float, ...]) -> Any:
    """``process_noise``'s field, with each filter's default (4 group values)."""
    return spec(
        default,
        kind="vec",
        length=(1, 4, STATE_DIM),
        lo=0.0,
        hi=100.0,
        doc="white-noise density per state added to each particle: one value for all, 4 "
        "groups (ρ m/√s, v m/s/√s, Λ rad/√s, ω rad/s/√s) or 12 values, each at most 100",
    )


def _inflation_spec(default: float) -> Any:
    """``likelihood_inflation``'s field, with each filter's default."""
    return spec(
        default,
        lo=1.0,
        hi=1e6,
        doc="λ: the LiDAR weights use p(z|x)^(1/λ) (≈ S·λ in the weights only; the landmark "
        "EKFs use the true R)",
    )


@dataclass(frozen=True)
class FastSlamSettings(GatedFields):
    """The settings both FastSLAM filters read (a base of their settings classes)."""

    n_particles: int = spec(500, kind="int", lo=1, doc="N, the number of particles")
    resample_threshold: float = spec(
        0.5, lo=0.0, hi=1.0, doc="resample when the ESS < this share of N"
    )
    process_noise: tuple[float, ...] = _noise_spec((0.0, 0.0, 0.0, 0.0))
    integrator: str = spec(
        "rk4",
        kind="str",
        choices=("rk4", "euler"),
        doc="the particles' integration scheme (one step per period)",
    )
    known_map_sigma: float = spec(
        1e-3, lo=0.0, lo_open=True, hi=1e3, doc="landmark std in known-map mode, m"
    )
    likelihood_inflation: float = _inflation_spec(1.0)
    roughening: float = spec(
        0.0,
        lo=0.0,
        hi=100.0,
        doc="K of Gordon et al. roughening after resampling (σ_j = K·std_j·N^(−1/12)); 0: off",
    )
    regularisation: float = spec(
        1.0,
        lo=0.0,
        hi=1e3,
        doc="c: after resampling, move the copies' poses (ρ, v, Λ) by the regularised-PF "
        "kernel with Liu-West shrinkage, bandwidth min(1, c·h_opt) (Musso et al. 2001); 0: off",
    )
    progressive_ess: float = spec(
        0.1,
        lo=0.0,
        hi=1.0,
        doc="a labeled scan that would leave fewer effective particles than this share of N "
        "is applied in tempered stages with kernel moves; 0: off",
    )
    anchor_gauge: bool = spec(
        True,
        kind="bool",
        doc="SLAM: keep the initial position and yaw uncertainty (the unobservable gauge) out "
        "of the particles and add it to the reported covariances",
    )
    nis_divergence: float = spec(
        1000.0,
        lo=0.0,
        doc="per-DOF NIS of the best 10 % of particles above which lock is considered lost; 0: off",
    )
    nis_divergence_s: float = spec(
        2.0,
        lo=0.0,
        doc="time the NIS must stay above nis_divergence before diverged = 1 (sticky), s",
    )
    new_landmark_likelihood: float = spec(
        1e-3,
        lo=0.0,
        lo_open=True,
        doc="p0 per rad²·m: a return is paired only if N(ν; 0, λS) >= p0; unpaired returns "
        "weigh p0",
    )

    def noise_density(self) -> FloatArray:
        """(12,) ``process_noise`` expanded per state (one value or 4 groups of 3)."""
        arr = np.asarray(self.process_noise, dtype=float)
        if arr.size == 1:
            return np.full(STATE_DIM, arr[0])
        return np.repeat(arr, 3) if arr.size == 4 else arr


@dataclass(frozen=True)
class DynamicFastSlamSettings(FastSlamSettings):
    """Settings of the dynamics-based, self-calibrating FastSLAM (``fastslam``)."""

    ONLY_FOR: ClassVar[dict[str, tuple[str, tuple[Any, ...]]]] = {
        "stage2_position": ("stage2", (True,))
    }
    process_noise: tuple[float, ...] = _noise_spec((0.02, 0.1, 0.003, 2e-5))
    likelihood_inflation: float = _inflation_spec(30.0)
    bias_tau_s: float = spec(
        100.0,
        lo=1e-3,
        hi=1e6,
        doc="drift time constant τ, s (seed 000 eq. 8, 10), from 1 ms to 1e6 s as imu.drift_tau_s",
    )
    accel_drift_sigma: float = spec(
        0.001, lo=0.0, hi=ACCEL_BIAS_MAX, doc="stationary std of b1_a, m/s² (at most 10)"
    )
    gyro_drift_sigma: float = spec(
        0.001, lo=0.0, hi=GYRO_BIAS_MAX, doc="stationary std of b1_ω, rad/s (at most 1)"
    )
    accel_bias_sigma: float = spec(
        0.01,
        lo=0.0,
        lo_open=True,
        hi=ACCEL_BIAS_MAX,
        doc="prior std of b0_a, m/s² (at most 10)",
    )
    gyro_bias_sigma: float = spec(
        0.01,
        lo=0.0,
        lo_open=True,
        hi=GYRO_BIAS_MAX,
        doc="prior std of b0_ω, rad/s (at most 1)",
    )
    mass_scale: float = spec(
        1.0,
        lo=0.1,
        hi=10.0,
        doc="the filter's mass = this × the nominal mass (0.1 to 10, as randomize.mass_scale)",
    )
    inertia_scale: float = spec(
        1.0,
        lo=0.1,
        hi=10.0,
        doc="the filter's inertia = this × the nominal inertia (seed 000 Fig. 14: 2.5; 0.1 to "
        "10, as randomize.inertia_scale)",
    )
    estimate_inertia: bool | None = spec(
        None,
        kind="bool",
        optional=True,
        doc="identify the principal moments of inertia (and the gyro bias) online from the "
        "gyro and the applied torque; null: when the inertia is diagonal",
    )
    inertia_prior_rel_sigma: float = spec(
        1.0,
        lo=0.0,
        lo_open=True,
        hi=100.0,
        doc="prior std of 1/J relative to the nominal model (at most 100)",
    )
    use_imu_likelihood: bool = spec(
        True, kind="bool", doc="multiply the weights by p(z^I | x^D, x̂^B)"
    )
    stage2: bool = spec(
        False, kind="bool", doc="seed 000 Table 2 step 8: ω from the gyro, ρ from the LiDAR"
    )
    stage2_position: bool = spec(
        True, kind="bool", doc="stage 2 also regenerates ρ (false: ω only)"
    )


@dataclass(frozen=True)
class KinematicFastSlamSettings(FastSlamSettings):
    """Settings of FastSLAM 1.0 on IMU strapdown kinematics (``fastslam_kinematic``).

    The ω group of ``process_noise`` is unused since ω is the input, and
    ``likelihood_inflation`` defaults to 1 (the unmodified FastSLAM 1.0 baseline).
    """

    process_noise: tuple[float, ...] = _noise_spec((0.02, 0.05, 0.005, 0.0))
    imu_noise_scale: float = spec(
        1.0,
        lo=0.0,
        hi=100.0,
        doc="factor on the IMU sample's σ used as the particles' input noise (at most 100)",
    )


_DEFAULTS = FastSlamSettings.defaults()


@dataclass(frozen=True)
class AssociationSettings:
    """Per-particle data association settings (``lidar.association: unknown``).

    Attributes:
        gate_probability: p of the individual χ²₃ gate on ``νᵀ S⁻¹ ν``, in (0, 1] (1: no gate).
        new_landmark_likelihood: p0 > 0, the likelihood density (per rad²·m of measurement
            space) of a return under the new-landmark/clutter hypothesis.
        confirm_hits: M of the M-of-N rule for tentative landmarks.
        confirm_window: N of the M-of-N rule.
    """

    gate_probability: float = _DEFAULTS["gate_probability"]
    new_landmark_likelihood: float = _DEFAULTS["new_landmark_likelihood"]
    confirm_hits: int = _DEFAULTS["confirm_hits"]
    confirm_window: int = _DEFAULTS["confirm_window"]

    @classmethod
    def of(cls, settings: FastSlamSettings) -> AssociationSettings:
        """The association settings of a filter's validated settings."""
        return cls(
            gate_probability=settings.gate_probability,
            new_landmark_likelihood=settings.new_landmark_likelihood,
            confirm_hits=settings.confirm_hits,
            confirm_window=settings.confirm_window,
        )

    @property
    def gate(self) -> float:
        """The χ²₃ quantile of :attr:`gate_probability` (inf when it is 1)."""
        return chi2_threshold(MEAS_DIM, self.gate_probability)
