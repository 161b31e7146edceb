"""Joint identification of the gyro bias and the principal moments of inertia.

Seed 000 §IV names online estimation of the inertia ("a continuous time RLS ... by converting
the three equations in (1) to a regression vector") as the remedy for the model mismatch of its
Fig. 14, and does not use it. This module is that regression in an integrated, bias-anchored
form, written as a small Kalman filter so that it starts from the filter's nominal model and
states its own uncertainty.

Model (seed 000 eq. 1 with ``J = diag(J_x, J_y, J_z)``): per body axis,
``ω̇_j = θ_j τ_j + g_j ω̃_j`` with ``θ_j = 1/J_j``, the gyroscopic products
``ω̃ = (q r, r p, p q)`` and ``g = ((J_y − J_z)/J_x, (J_z − J_x)/J_y, (J_x − J_y)/J_z)``
(``−θ_j`` times the component of ``ω × Jω``). Integrated from the start of the flight,

    ω_j(t) = ω_j(0) + θ_j Φ_j(t) + g_j Ψ_j(t),    Φ(t) = ∫₀ᵗ τ ds,    Ψ(t) = ∫₀ᵗ ω̃ ds,

and the gyro (seed 000 eq. 6) reads ``z_j(t) = ω_j(t) + b_j + v_j``, so per axis

    z_j(t) = c_j + θ_j Φ_j(t) + g_j Ψ_j(t) + v_j,    c_j = b_j + ω_j(0),

a linear measurement of ``β_j = (c_j, θ_j, g_j)`` with the known, time-varying row
``H = [1, Φ_j(t), Ψ_j(t)]``: the Kalman filter is the exact recursive least-squares solution.
The torque τ is the applied control; ``ω̃`` is formed from the gyro minus ``ĉ``, with ĉ
applied when the integrals of the raw readings are read (:func:`regressors`). Treating g
as a parameter of its own keeps the regressors free of Ĵ. (Integrating ``τ − ω × Ĵω`` with the
Ĵ of each moment, as a first version did, baked the early, still wrong Ĵ of one axis into the
others: on ``fastslam_out_of_view_600s``, whose DF-LQR yaws at 3 rad/s in the first second,
a 1.4 % error of Ĵ_x gave a 1.5 % error of Ĵ_y and a gyro bias of 9e-3 rad/s after 3 s,
for a gyro without bias.) The filter's model takes ``J = 1/θ̂``; ĝ is not fed back (a
consistency check only).

The regressors depend only on torques applied and rates measured *before* the reading's
period ends, not on its noise: they are predetermined, so the estimate is consistent even
with the controller in the loop (a regression on gyro *differences* is not: there the torque
reacts to the noise of the first reading and the inertia came out 11–16 % low in closed
loop). Starting at rest (``ω(0) ≈ 0``) makes ``c`` the gyro bias itself; its drift enters as
random-walk process noise on ``c``.

An integrating gyro reports the mean rate over its sample period, so the regressors are taken
at the middle of the period.

The per-sample arithmetic is numba kernels (:func:`regression_step`, :func:`regression_measure`)
on the (3, 3) means and (3, 3, 3) covariances in place: it runs at every IMU period of the
dynamics-based FastSLAM.
"""

from __future__ import annotations

import math

import numpy as np

from quadslam_env.models.jit import kernel
from quadslam_env.types import FloatArray

THETA_RANGE = 10.0
"""θ̂ is kept within [θ₀/10, 10 θ₀]: the identified inertia is at most 10× off the nominal."""
MODEL_SIGMA = 1e-4
"""Std in rad/s added (in quadrature) to the gyro noise for the regression's own modelling error
(mid-period Φ, the approximate ω × Jω term); it also keeps a noise-free gyro usable."""
NIS_WINDOW_S = 1.0
"""Time constant in s of the running mean of the normalised innovation squared (NIS)."""
MAX_NIS = 9.0
"""The estimate is :attr:`GyroTorqueRegression.usable` while the running NIS of every axis is
below this, i.e. while the rigid-body model explains the gyro data."""
PARAMS = 3
"""Regression parameters per axis: ``(c_j, θ_j, g_j)``."""


@kernel
def inertia_differences(J: FloatArray, out: FloatArray) -> None:
    """``d = (J_y − J_z, J_z − J_x, J_x − J_y)`` (3,) in kg·m² for principal moments ``J`` (3,).

    ``ω × Jω = −d ⊙ ω̃`` with ``ω̃ = (q r, r p, p q)`` (seed 000 eq. 1, diagonal J); the
    gyroscopic coefficients of the regression are ``g = d / J``.
    """
    out[0] = J[1] - J[2]
    out[1] = J[2] - J[0]
    out[2] = J[0] - J[1]


@kernel
def clipped_theta(mean: FloatArray, theta0: FloatArray, out: FloatArray) -> None:
    """``out = θ̂`` (3,) in 1/(kg·m²): ``mean[:, 1]`` kept within [θ₀/10, 10 θ₀]."""
    for j in range(3):
        out[j] = min(max(mean[j, 1], theta0[j] / THETA_RANGE), theta0[j] * THETA_RANGE)


@kernel
def regression_measure(
    mean: FloatArray,
    cov: FloatArray,
    gyro: FloatArray,
    sigma: float,
    rows: FloatArray,
    nis: FloatArray,
) -> None:
    """Kalman update with ``z_j = H_j β_j + v_j``, ``H_j = rows[j]``, per axis, in place.

    Args:
        mean: (3, 3) means ``β_j = (c_j, θ_j, g_j)``, updated. cov: (3, 3, 3) covariances,
            updated (symmetrised).
        gyro: (3,) reading ``z`` in rad/s. sigma: Noise std of ``v`` in rad/s (> 0).
        rows: (3, 3) rows ``H_j = (1, Φ_j, Ψ_j)``. nis: (3,) receives ``ν²/S`` per axis.
    """
    n = PARAMS
    var = sigma**2
    ph = np.empty(n)
    k = np.empty(n)
    for j in range(3):
        P, h = cov[j], rows[j]
        S = var
        nu = gyro[j]
        for a in range(n):
            acc = 0.0
            for b in range(n):
                acc += P[a, b] * h[b]
            ph[a] = acc  # P Hᵀ
            S += h[a] * acc
            nu -= h[a] * mean[j, a]
        for a in range(n):
            k[a] = ph[a] / S
            mean[j, a] += k[a] * nu
        for a in range(n):
            for b in range(a, n):
                v = 0.5 * ((P[a, b] - k[a] * ph[b]) + (P[b, a] - k[b] * ph[a]))
                P[a, b] = v
                P[b, a] = v
        nis[j] = nu * nu / S


INTEGRALS = 4
"""Rows of :attr:`GyroTorqueRegression.integrals`: ``∫τ``, ``∫z_m z_n``, ``∫z``, ``t``."""


@kernel
def regressors(integrals: FloatArray, c: FloatArray, out: FloatArray) -> None:
    """``Φ = ∫τ`` and ``Ψ = ∫ω̃`` with ``ω = z − c`` into ``out`` (2, 3).

    ``∫(z_m − c_m)(z_n − c_n) = ∫z_m z_n − c_n ∫z_m − c_m ∫z_n + c_m c_n t`` with
    ``(m, n) = (y, z), (z, x), (x, y)``: the integrals are of the raw readings and the bias
    enters when they are read, so a still wrong early ĉ is not integrated into Ψ.

    Args:
        integrals: (4, 3) rows ``∫τ`` (N·m·s), ``∫z_m z_n`` (rad²/s), ``∫z`` (rad), ``t`` (s).
        c: (3,) gyro bias ``c`` in rad/s.
    """
    t = integrals[3, 0]
    for j in range(3):
        m, n = (j + 1) % 3, (j + 2) % 3
        out[0, j] = integrals[0, j]
        out[1, j] = (
            integrals[1, j] - c[n] * integrals[2, m] - c[m] * integrals[2, n] + c[m] * c[n] * t
        )


@kernel
def angular_impulse(
    integrals: FloatArray, theta: FloatArray, c: FloatArray, out: FloatArray
) -> None:
    """``∫(τ − ω × Jω) = Φ + d ⊙ Ψ`` (3,) in N·m·s for ``J = 1/θ`` and the bias ``c``.

    d from :func:`inertia_differences`, Φ and Ψ from :func:`regressors`.
    """
    phi_psi, J, d = np.empty((2, 3)), np.empty(3), np.empty(3)
    regressors(integrals, c, phi_psi)
    for j in range(3):
        J[j] = 1.0 / theta[j]
    inertia_differences(J, d)
    for j in range(3):
        out[j] = phi_psi[0, j] + d[j] * phi_psi[1, j]


@kernel
def regression_step(
    mean: FloatArray,
    cov: FloatArray,
    integrals: FloatArray,
    nis: FloatArray,
    gyro: FloatArray,
    torque: FloatArray,
    dt: float,
    sigma: float,
    rate_var: float,
    gain: float,
) -> None:
    """One gyro sample: advance the integrals, random-walk ``c``, update, track the NIS.

    Args:
        mean, cov: (3, 3), (3, 3, 3) posterior, updated in place.
        integrals: (4, 3) integrals of :func:`regressors` at the end of the last period,
            advanced in place (the reading and the torque are held over the period).
        nis: (3,) running mean of ``ν²/S``, updated with weight ``gain``.
        gyro: (3,) reading in rad/s. torque: (3,) applied torque in N·m. dt: Period in s.
        sigma: Noise std of the reading in rad/s. rate_var: Random-walk variance density of
            ``c`` in rad²/s³. gain: Weight of the new NIS in the running mean.
    """
    inc = np.empty((INTEGRALS, 3))
    for j in range(3):
        m, n = (j + 1) % 3, (j + 2) % 3
        inc[0, j] = torque[j]
        inc[1, j] = gyro[m] * gyro[n]
        inc[2, j] = gyro[j]
        inc[3, j] = 1.0
    mid = np.empty((INTEGRALS, 3))  # at the middle of the period, for the reading
    for a in range(INTEGRALS):
        for j in range(3):
            mid[a, j] = integrals[a, j] + 0.5 * dt * inc[a, j]
            integrals[a, j] += dt * inc[a, j]
    c = np.empty(3)
    for j in range(3):
        c[j] = mean[j, 0]
    phi_psi = np.empty((2, 3))
    regressors(mid, c, phi_psi)
    rows = np.empty((3, PARAMS))
    for j in range(3):
        m, n = (j + 1) % 3, (j + 2) % 3
        rows[j, 0], rows[j, 1], rows[j, 2] = 1.0, phi_psi[0, j], phi_psi[1, j]
        # c is a random walk (bias drift), θ and g constants. The gyro noise in ω̃ (variance
        # σ² (ω_m² + ω_n²)) makes Ψ a random walk around its true value; c absorbs g δΨ.
        spread = (gyro[m] - c[m]) ** 2 + (gyro[n] - c[n]) ** 2
        cov[j, 0, 0] += rate_var * dt + (mean[j, 2] * dt * sigma) ** 2 * spread
    new = np.empty(3)
    regression_measure(mean, cov, gyro, sigma, rows, new)
    for j in range(3):
        nis[j] += gain * (new[j] - nis[j])


class GyroTorqueRegression:
    """Three independent 3-state Kalman filters over ``(c_j, θ_j, g_j)``, one per body axis.

    Args:
        inertia_prior: (3,) prior principal moments ``J₀`` in kg·m² (the filter's model).
        inertia_rel_sigma: Prior std of θ relative to ``θ₀ = 1/J₀``, and the prior std of
            each ``g_j`` (|g_j| ≤ 1 for any principal moments: ``|J_y − J_z| ≤ J_x``).
        bias_sigma: Prior std of ``c`` (gyro bias plus initial rate) in rad/s.
        bias_rate_sigma: Random-walk density of ``c`` in rad/s/√s (covers the bias drift).

    Attributes:
        mean: (3, 3) posterior means, rows ``(c_j, θ_j, g_j)``.
        cov: (3, 3, 3) posterior covariances.
    """

    def __init__(
        self,
        inertia_prior: FloatArray,
        inertia_rel_sigma: float,
        bias_sigma: float,
        bias_rate_sigma: float,
    ) -> None:
        j0 = np.asarray(inertia_prior, dtype=float).reshape(3)
        self.theta0 = 1.0 / j0
        d0 = np.empty(3)
        inertia_differences(j0, d0)
        self.g0 = d0 / j0  # prior gyroscopic coefficients
        self.inertia_rel_sigma = float(inertia_rel_sigma)
        self.bias_sigma = float(bias_sigma)
        self.bias_rate_sigma = float(bias_rate_sigma)
        self.reset()

    def reset(self) -> None:
        """Back to the prior; ``Φ = Ψ = 0`` (the flight starts now)."""
        self.mean = np.column_stack([np.zeros(3), self.theta0, self.g0])
        self.cov = np.zeros((3, PARAMS, PARAMS))
        self.cov[:, 0, 0] = self.bias_sigma**2
        self.cov[:, 1, 1] = (self.inertia_rel_sigma * self.theta0) ** 2
        self.cov[:, 2, 2] = self.inertia_rel_sigma**2
        self.integrals = np.zeros((INTEGRALS, 3))  # of :func:`regressors`, flight so far
        self.nis = np.ones(3)  # running mean of ν²/S per axis
        self.n_updates = 0

    @property
    def theta(self) -> FloatArray:
        """(3,) posterior mean of ``1/J`` in 1/(kg·m²), kept within :data:`THETA_RANGE`."""
        out = np.empty(3)
        clipped_theta(self.mean, self.theta0, out)
        return out

    @property
    def usable(self) -> bool:
        """Whether the data are consistent with the model: running NIS < :data:`MAX_NIS` on
        every axis. The posterior mean is used from the first sample (it is never worse than
        the prior); random or corrupted gyro/torque streams fail this test within a few
        samples, after which the filter falls back to its nominal model."""
        nis = self.nis
        return bool(nis[0] < MAX_NIS and nis[1] < MAX_NIS and nis[2] < MAX_NIS)

    @property
    def inertia(self) -> FloatArray:
        """(3,) current estimate of the principal moments in kg·m²."""
        return 1.0 / self.theta

    @property
    def gyro_bias(self) -> FloatArray:
        """(3,) posterior mean of ``c`` in rad/s (the gyro bias for a start at rest)."""
        return self.mean[:, 0].copy()

    def relative_std(self) -> FloatArray:
        """(3,) posterior std of θ relative to θ̂ (a convergence diagnostic)."""
        return np.sqrt(self.cov[:, 1, 1]) / self.theta

    def update(self, gyro: FloatArray, gyro_sigma: float, torque: FloatArray, dt: float) -> None:
        """One gyro sample and the torque applied over its period of ``dt`` s.

        Args:
            gyro: (3,) gyro reading in rad/s (mean rate over the period).
            gyro_sigma: Its noise std in rad/s.
            torque: (3,) applied torque over the period in N·m.
            dt: Period in s.
        """
        regression_step(
            self.mean,
            self.cov,
            self.integrals,
            self.nis,
            np.asarray(gyro, dtype=float),
            np.asarray(torque, dtype=float),
            float(dt),
            math.hypot(float(gyro_sigma), MODEL_SIGMA),
            self.bias_rate_sigma**2,
            min(1.0, dt / NIS_WINDOW_S),
        )
        self.n_updates += 1

    def measure(
        self, gyro: FloatArray, sigma: float, phi: FloatArray, psi: FloatArray
    ) -> FloatArray:
        """Kalman update with ``z_j = c_j + θ_j Φ_j + g_j Ψ_j + v_j`` for given regressors.

        Args:
            gyro: (3,) reading ``z`` in rad/s.
            sigma: Noise std of ``v`` in rad/s (> 0).
            phi: (3,) ``Φ = ∫τ`` in N·m·s at the reading's time. psi: (3,) ``Ψ = ∫ω̃`` in rad²/s.

        Returns:
            (3,) normalised innovation squared ``ν²/S`` of each axis.
        """
        nis = np.empty(3)
        rows = np.column_stack([np.ones(3), np.asarray(phi, float), np.asarray(psi, float)])
        regression_measure(
            self.mean, self.cov, np.asarray(gyro, dtype=float), float(sigma), rows, nis
        )
        self.n_updates += 1
        return nis

    def __repr__(self) -> str:
        inertia = ", ".join(f"{v:.5g}" for v in self.inertia)
        bias = ", ".join(f"{v:.3g}" for v in self.gyro_bias)
        rel = max(float(v) for v in self.relative_std())
        return (
            f"GyroTorqueRegression(J=({inertia}) kg·m², c=({bias}) rad/s, "
            f"θ rel. std ≤ {rel:.2g}, n={self.n_updates})"
        )
