"""EKF-SLAM for a quadcopter with an IMU and a range–bearing LiDAR (seed 001 §2.3).

State (seed 001 eq. 21–22), all in one preallocated vector ``x``::

    x = (s, b, m)
    s = (ρ [m, N], v_B [m/s, B], Λ = (φ, θ, ψ) [rad])      9 vehicle states (eq. 21)
    b = (b_ω [rad/s, B], b_az [m/s²])                       4 IMU biases (only with
                                                             ``estimate_imu_bias``)
    m = (l_1, …, l_nm) [m, N]                               3 per mapped landmark

The covariance ``P`` (eq. 23) lives in a square buffer whose capacity doubles when the map
outgrows it, so registering a landmark does not reallocate every time.

Prediction (eq. 24–29) runs once per IMU sample with the input ``λ = (ã_z, ω̃)`` (eq. 25) minus
the bias estimates. The mean is integrated with RK4 (input held over the sample period), the
covariance with the second-order transition matrix ``Φ = I + F dt + ½ F² dt²`` of eq. 27:
``P_vv ← Φ P_vv Φᵀ + Q_d`` and ``P_vm ← Φ P_vm`` (eq. 29), ``P_mm`` untouched, so the cost is
linear in the map size. ``Q_d = Q dt + Γ R_λ Γᵀ`` with ``Γ = ∫₀^dt e^{Fτ} dτ ∂f/∂λ``: the IMU
white noise (per-sample standard deviation held over the sample period) is mapped into the
state, which the paper's Tables 6–7 leave to Q.

Update (eq. 37–43): the observed mapped landmarks are stacked into one update that only touches
``P[:, idx]`` with ``idx = [s, m_κ]``; each landmark is first χ²-gated on its own 3-DOF NIS.
Registration (eq. 44–53) then augments ``x`` and ``P`` with the new landmarks.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from scipy.special import gammaincinv

from estimators.base import Estimate, check_kwargs, register
from quadslam_env.measurements import Control, ImuSample, LidarScan
from quadslam_env.models.dynamics import GRAVITY
from quadslam_env.models.lidar import (
    inverse_jacobians,
    lidar_inverse,
    lidar_jacobians,
    lidar_measure,
    measurement_residual,
)
from quadslam_env.models.rotations import FloatArray, dcm_from_euler

POSE_DIM = 9
"""Size of the vehicle state s = (ρ, v_B, Λ)."""
BIAS_DIM = 4
"""Size of the bias block b = (b_ω (3), b_az (1)) when biases are estimated."""

_PAPER_Q_UNKNOWN = (0.2, 0.2, 0.05, 0.01, 0.01, 0.01, 0.02, 0.2, 0.2)  # seed 001 Table 7
_INITIAL_LANDMARK_CAPACITY = 32
_TWO_PI = 2.0 * math.pi
_MAX_PITCH = math.radians(89.0)
"""|θ̂| beyond which D(Λ) (1/cos θ) is treated as singular and the filter flagged diverged."""
_I3 = np.eye(3)
_AR3 = np.arange(3)


def _wrap(a: float) -> float:
    """Scalar angle wrap to (-π, π]."""
    w = math.remainder(a, _TWO_PI)
    return math.pi if w == -math.pi else w


def _derivative(s: list[float], az: float, p: float, q: float, r: float) -> list[float]:
    """Scalar ``f_s(s, λ)`` of seed 001 eq. 24 (see :func:`process_derivative`)."""
    u, v, w, phi, theta, psi = s[3], s[4], s[5], s[6], s[7], s[8]
    cf, sf = math.cos(phi), math.sin(phi)
    ct, st = math.cos(theta), math.sin(theta)
    cp, sp = math.cos(psi), math.sin(psi)
    g = GRAVITY
    a = sf * q + cf * r
    return [
        ct * cp * u + (sf * st * cp - cf * sp) * v + (cf * st * cp + sf * sp) * w,
        ct * sp * u + (sf * st * sp + cf * cp) * v + (cf * st * sp - sf * cp) * w,
        -st * u + sf * ct * v + cf * ct * w,
        r * v - q * w - g * st,
        p * w - r * u + g * sf * ct,
        q * u - p * v + g * cf * ct + az,
        p + a * st / ct,
        cf * q - sf * r,
        a / ct,
    ]


def _jacobian_rows(
    s: list[float], p: float, q: float, r: float
) -> tuple[list[list[float]], list[list[float]]]:
    """Scalar ``F = ∂f_s/∂s`` (eq. 28) and ``G = ∂f_s/∂λ`` as nested lists (9×9, 9×4)."""
    u, v, w, phi, theta, psi = s[3], s[4], s[5], s[6], s[7], s[8]
    cf, sf = math.cos(phi), math.sin(phi)
    ct, st = math.cos(theta), math.sin(theta)
    cp, sp = math.cos(psi), math.sin(psi)
    g = GRAVITY
    c00, c01, c02 = ct * cp, sf * st * cp - cf * sp, cf * st * cp + sf * sp
    c10, c11, c12 = ct * sp, sf * st * sp + cf * cp, cf * st * sp - sf * cp
    c20, c21, c22 = -st, sf * ct, cf * ct
    xd = c00 * u + c01 * v + c02 * w
    yd = c10 * u + c11 * v + c12 * w
    # ∂C/∂φ v = C (e1 × v); ∂C/∂θ v = C ((C1ᵀ e2) × v); ∂C/∂ψ v = e3 × (C v).
    e0, e1, e2 = cf * w + sf * v, -sf * u, -cf * u
    sec = 1.0 / ct
    tt = st * sec
    a = sf * q + cf * r
    b = cf * q - sf * r
    F = [
        [0.0, 0.0, 0.0, c00, c01, c02, c02 * v - c01 * w, c00 * e0 + c01 * e1 + c02 * e2, -yd],
        [0.0, 0.0, 0.0, c10, c11, c12, c12 * v - c11 * w, c10 * e0 + c11 * e1 + c12 * e2, xd],
        [0.0, 0.0, 0.0, c20, c21, c22, c22 * v - c21 * w, c20 * e0 + c21 * e1 + c22 * e2, 0.0],
        [0.0, 0.0, 0.0, 0.0, r, -q, 0.0, -g * ct, 0.0],
        [0.0, 0.0, 0.0, -r, 0.0, p, g * c22, -g * sf * st, 0.0],
        [0.0, 0.0, 0.0, q, -p, 0.0, -g * c21, -g * cf * st, 0.0],
        [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, b * tt, a * sec * sec, 0.0],
        [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, -a, 0.0, 0.0],
        [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, b * sec, a * tt * sec, 0.0],
    ]
    G = [
        [0.0, 0.0, 0.0, 0.0],
        [0.0, 0.0, 0.0, 0.0],
        [0.0, 0.0, 0.0, 0.0],
        [0.0, 0.0, -w, v],
        [0.0, w, 0.0, -u],
        [1.0, -v, u, 0.0],
        [0.0, 1.0, sf * tt, cf * tt],
        [0.0, 0.0, cf, -sf],
        [0.0, 0.0, sf * sec, cf * sec],
    ]
    return F, G


def process_derivative(s: FloatArray, accel_z: float, gyro: FloatArray) -> FloatArray:
    """Process model ``ṡ = f_s(s, λ)`` of seed 001 eq. 24 (noise-free).

    ``ρ̇ = C_NB v``, ``v̇ = -ω×v + C_NBᵀ g n3 + a_z b3``, ``Λ̇ = D(Λ) ω``.

    Args:
        s: (9,) vehicle state (ρ [m, N], v_B [m/s, B], Λ [rad]).
        accel_z: Bias-corrected specific force along b3 in m/s² (``-g`` in hover).
        gyro: (3,) bias-corrected body rates ω in rad/s.

    Returns:
        (9,) time derivative of s.
    """
    p, q, r = (float(c) for c in gyro)
    return np.array(_derivative(np.asarray(s, float).tolist(), float(accel_z), p, q, r))


def process_jacobians(
    s: FloatArray, accel_z: float, gyro: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """Analytic Jacobians of :func:`process_derivative` (seed 001 eq. 28).

    Args:
        s: (9,) vehicle state.
        accel_z: Specific force along b3 in m/s² (does not enter the Jacobians).
        gyro: (3,) body rates in rad/s.

    Returns:
        ``(F, G)``: ``F = ∂f_s/∂s`` (9, 9) and ``G = ∂f_s/∂λ`` (9, 4) for ``λ = (a_z, ω)``.
        With bias states ``b = (b_ω, b_az)`` and ``λ = λ̃ - b``, ``∂f/∂b_ω = -G[:, 1:4]`` and
        ``∂f/∂b_az = -G[:, 0]``.
    """
    del accel_z
    p, q, r = (float(c) for c in gyro)
    F, G = _jacobian_rows(np.asarray(s, float).tolist(), p, q, r)
    return np.array(F), np.array(G)


def _check_nonneg(key: str, value: float) -> float:
    value = float(value)
    if not (math.isfinite(value) and value >= 0.0):
        raise ValueError(f"estimator.params.{key}: got {value!r}; allowed: a finite number >= 0")
    return value


@register("ekf_slam")
class EkfSlam:
    """EKF-SLAM of seed 001 §2.3 with known data association.

    Args:
        vehicle: Nominal vehicle parameters (unused: the process model is driven by the IMU).
        **params: Settings (all optional):

            ``process_noise`` (list of 9 floats ≥ 0, default seed 001 Table 7
            ``[0.2, 0.2, 0.05, 0.01, 0.01, 0.01, 0.02, 0.2, 0.2]``): diagonal of the
            continuous-time process-noise spectral density Q over (ρ, v_B, Λ), in m²/s,
            m²/s³, rad²/s. Table 6 (known landmarks) uses ``[0.01]*6 + [0.02]*3``.

            Known-map mode (localisation only, the paper's known-landmarks case) is selected
            by passing ``known_landmarks=(ids, positions)`` to :meth:`reset` (the env does so
            when the scenario sets ``estimator.known_map: true``); those positions are exact
            and are not states.

            ``estimate_imu_bias`` (bool, default False): augment the state with the gyro bias
            b_ω (3) and the accelerometer z bias b_az (1); these are the only IMU axes the
            model uses (λ = (ã_z, ω̃), seed 001 eq. 25). Random walks with the settings below.

            ``gyro_bias_sigma0`` (float ≥ 0, default 0.01 rad/s): initial bias std per axis.

            ``accel_bias_sigma0`` (float ≥ 0, default 0.05 m/s²): initial z-bias std.

            ``gyro_bias_walk`` (float ≥ 0, default 1e-4 rad/s/√s): random-walk density.

            ``accel_bias_walk`` (float ≥ 0, default 1e-3 m/s²/√s): random-walk density.

            ``gate_probability`` (float in (0, 1], default 0.99): per-landmark χ² gate
            (3 DOF; 0.99 → NIS threshold 11.345). 1.0 disables gating.

            ``imu_noise_in_q`` (bool, default True): add the IMU white noise mapped through
            ``∂f/∂λ`` to the discrete process noise (needed for consistency; False reproduces
            the paper, which only uses Q).

    Raises:
        ValueError: Unknown key, wrong type or out-of-range value (the message names the key,
            the value and what is allowed).
    """

    def __init__(self, vehicle: Any = None, **params: Any) -> None:
        check_kwargs(
            "estimator.params",
            params,
            {
                "process_noise": (list, tuple, np.ndarray),
                "estimate_imu_bias": bool,
                "gyro_bias_sigma0": (float, int),
                "accel_bias_sigma0": (float, int),
                "gyro_bias_walk": (float, int),
                "accel_bias_walk": (float, int),
                "gate_probability": (float, int),
                "imu_noise_in_q": bool,
            },
        )
        self.vehicle = vehicle
        q = params.get("process_noise", _PAPER_Q_UNKNOWN)
        if len(q) != POSE_DIM or not all(
            isinstance(e, float | int) and not isinstance(e, bool) for e in q
        ):
            raise ValueError(
                f"estimator.params.process_noise: got {q!r}; allowed: a list of 9 numbers >= 0"
            )
        q_diag = [_check_nonneg("process_noise", e) for e in q]
        self.known_map = False  # set by reset(known_landmarks=...)
        self.estimate_imu_bias = bool(params.get("estimate_imu_bias", False))
        self.imu_noise_in_q = bool(params.get("imu_noise_in_q", True))
        self.gyro_bias_sigma0 = _check_nonneg(
            "gyro_bias_sigma0", params.get("gyro_bias_sigma0", 0.01)
        )
        self.accel_bias_sigma0 = _check_nonneg(
            "accel_bias_sigma0", params.get("accel_bias_sigma0", 0.05)
        )
        gyro_walk = _check_nonneg("gyro_bias_walk", params.get("gyro_bias_walk", 1e-4))
        accel_walk = _check_nonneg("accel_bias_walk", params.get("accel_bias_walk", 1e-3))
        prob = float(params.get("gate_probability", 0.99))
        if not 0.0 < prob <= 1.0:
            raise ValueError(
                f"estimator.params.gate_probability: got {prob!r}; allowed: 0 < p <= 1"
            )
        self.gate_probability = prob
        self.gate_threshold = math.inf if prob >= 1.0 else float(2.0 * gammaincinv(1.5, prob))

        self._nv = POSE_DIM + (BIAS_DIM if self.estimate_imu_bias else 0)
        qc = q_diag + ([gyro_walk**2] * 3 + [accel_walk**2] if self.estimate_imu_bias else [])
        self._qc = np.array(qc)
        self._qc_dt = -1.0
        self._qd_diag = np.zeros((self._nv, self._nv))
        self._eye_v = np.eye(self._nv)
        self._pose_cols = np.arange(POSE_DIM)
        self._init_buffers(self._nv + 3 * _INITIAL_LANDMARK_CAPACITY)
        self._rates = np.zeros(3)
        self._reset_diagnostics()

    # ------------------------------------------------------------------ state handling
    def _init_buffers(self, capacity: int) -> None:
        self._x = np.zeros(capacity)
        self._P = np.zeros((capacity, capacity))
        self._n = self._nv
        self._slot: dict[int, int] = {}
        self._ids: list[int] = []
        self._known_ids = np.zeros(0, dtype=int)
        self._known_pos = np.zeros((0, 3))
        self._known_index: dict[int, int] = {}

    def _reset_diagnostics(self) -> None:
        self._nis = math.nan
        self._nis_dof = 0
        self._n_rejected = 0
        self._n_rejected_last = 0
        self._n_updates = 0
        self._diverged = False

    def _ensure_capacity(self, size: int) -> None:
        cap = self._x.shape[0]
        if size <= cap:
            return
        new_cap = max(2 * cap, size)
        n = self._n
        x = np.zeros(new_cap)
        x[:n] = self._x[:n]
        P = np.zeros((new_cap, new_cap))
        P[:n, :n] = self._P[:n, :n]
        self._x, self._P = x, P

    @property
    def capacity(self) -> int:
        """Current length of the state buffer (grows by doubling)."""
        return int(self._x.shape[0])

    @property
    def state_dim(self) -> int:
        """Current size n of the total state x = (s, b, m)."""
        return self._n

    def reset(
        self,
        mean0: FloatArray,
        cov0: FloatArray,
        rng: np.random.Generator,
        known_landmarks: tuple[np.ndarray, FloatArray] | None = None,
    ) -> None:
        """Start a new run (seed 001 §2.3.1: no landmarks are mapped at the start).

        Args:
            mean0: (12,) initial mean (ρ [m, N], v_B [m/s], Λ [rad], ω [rad/s]); the first
                9 entries become ŝ, ω is reported until the first IMU sample arrives.
            cov0: (12, 12) initial covariance; its (9, 9) top-left block becomes ``P_ss``.
            rng: Unused (the EKF is deterministic); accepted for the protocol.
            known_landmarks: ``(ids (L,), positions (L, 3) [m, N])`` to localise against a
                known map (no landmark states); ``None`` for full SLAM.

        Raises:
            ValueError: Wrong shapes, non-finite values, or a missing known map.
        """
        del rng
        mean0 = np.asarray(mean0, dtype=float)
        cov0 = np.asarray(cov0, dtype=float)
        if mean0.shape != (12,) or not np.isfinite(mean0).all():
            raise ValueError(f"reset: mean0 must be a finite (12,) array, got shape {mean0.shape}")
        if cov0.shape != (12, 12) or not np.isfinite(cov0).all():
            raise ValueError(f"reset: cov0 must be a finite (12, 12) array, got shape {cov0.shape}")
        self._init_buffers(self._nv + 3 * _INITIAL_LANDMARK_CAPACITY)
        nv = self._nv
        self._x[:POSE_DIM] = mean0[:POSE_DIM]
        for i in (6, 8):
            self._x[i] = _wrap(float(self._x[i]))
        P0 = cov0[:POSE_DIM, :POSE_DIM]
        self._P[:POSE_DIM, :POSE_DIM] = 0.5 * (P0 + P0.T)
        if self.estimate_imu_bias:
            b_var = [self.gyro_bias_sigma0**2] * 3 + [self.accel_bias_sigma0**2]
            self._P[POSE_DIM:nv, POSE_DIM:nv] = np.diag(b_var)
        self._rates = mean0[9:12].copy()
        self._reset_diagnostics()
        self.known_map = known_landmarks is not None
        if known_landmarks is not None:
            ids = np.asarray(known_landmarks[0]).astype(int).reshape(-1)
            pos = np.asarray(known_landmarks[1], dtype=float).reshape(-1, 3)
            if ids.shape[0] != pos.shape[0] or not np.isfinite(pos).all():
                raise ValueError(
                    "reset: known_landmarks must be (ids (L,), finite positions (L, 3)), got "
                    f"{ids.shape[0]} ids and {pos.shape[0]} positions"
                )
            self._known_ids = ids.copy()
            self._known_pos = pos.copy()
            self._known_index = {int(i): k for k, i in enumerate(ids.tolist())}

    # ------------------------------------------------------------------ prediction
    def predict(self, imu: ImuSample, control: Control, dt: float) -> None:
        """Propagate over one IMU sample period (seed 001 eq. 24–29).

        Args:
            imu: Sample with ``accel`` (3,) specific force [m/s², B] (only the z component is
                used, eq. 25), ``gyro`` (3,) [rad/s, B], and their per-sample noise stds.
            control: Applied control (unused: the process is driven by the IMU, eq. 24).
            dt: Sample period in s (> 0).

        Raises:
            ValueError: If ``dt`` is not a positive finite number.
        """
        del control
        if not 0.0 < dt < math.inf:
            raise ValueError(f"predict: dt must be a positive finite number of seconds, got {dt}")
        nv, n = self._nv, self._n
        x, P = self._x, self._P
        p, q, r = imu.gyro.tolist()
        az = float(imu.accel[2])
        xv = x[:nv].tolist()
        s = xv[:POSE_DIM]
        if self.estimate_imu_bias:
            p -= xv[9]
            q -= xv[10]
            r -= xv[11]
            az -= xv[12]
        # Mean: RK4 with the input held over the sample period (eq. 26).
        h2 = 0.5 * dt
        k1 = _derivative(s, az, p, q, r)
        k2 = _derivative([a + h2 * b for a, b in zip(s, k1, strict=True)], az, p, q, r)
        k3 = _derivative([a + h2 * b for a, b in zip(s, k2, strict=True)], az, p, q, r)
        k4 = _derivative([a + dt * b for a, b in zip(s, k3, strict=True)], az, p, q, r)
        h6 = dt / 6.0
        s_new = [
            a + h6 * (b + 2.0 * (c + d) + e)
            for a, b, c, d, e in zip(s, k1, k2, k3, k4, strict=True)
        ]
        # Covariance (eq. 27–29): Φ = I + A + ½A², A = F dt; Γ = (I dt + ½ F dt²) G.
        Frows, Grows = _jacobian_rows(s, p, q, r)
        sa = imu.accel_sigma * dt if self.imu_noise_in_q else 0.0
        sg = imu.gyro_sigma * dt if self.imu_noise_in_q else 0.0
        if self.estimate_imu_bias:
            Frows = [
                [e * dt for e in fr] + [-gr[1] * dt, -gr[2] * dt, -gr[3] * dt, -gr[0] * dt]
                for fr, gr in zip(Frows, Grows, strict=True)
            ] + [[0.0] * nv] * BIAS_DIM
            Grows = [[gr[0] * sa, gr[1] * sg, gr[2] * sg, gr[3] * sg] for gr in Grows] + [
                [0.0] * 4
            ] * BIAS_DIM
        else:
            Frows = [[e * dt for e in fr] for fr in Frows]
            Grows = [[gr[0] * sa, gr[1] * sg, gr[2] * sg, gr[3] * sg] for gr in Grows]
        A = np.array(Frows)
        M = 0.5 * A
        M += self._eye_v
        Phi = A @ M
        Phi += self._eye_v
        Gam = M @ np.array(Grows)
        if dt != self._qc_dt:
            np.fill_diagonal(self._qd_diag, self._qc * dt)
            self._qc_dt = dt
        T = Phi @ P[:nv, :n]
        Pvv = T[:, :nv] @ Phi.T
        Pvv += Pvv.T
        Pvv *= 0.5
        Pvv += Gam @ Gam.T
        Pvv += self._qd_diag
        if not (
            all(map(math.isfinite, s_new))
            and abs(s_new[7]) < _MAX_PITCH
            and math.isfinite(float(T.sum() + Pvv.sum()))
        ):
            self._diverged = True
            return
        P[:nv, :nv] = Pvv
        if n > nv:
            Tm = T[:, nv:]
            P[:nv, nv:n] = Tm
            P[nv:n, :nv] = Tm.T
        s_new[6] = _wrap(s_new[6])
        s_new[8] = _wrap(s_new[8])
        x[:POSE_DIM] = s_new
        self._rates = np.array([p, q, r])

    # ------------------------------------------------------------------ update
    def _landmark_cols(self, slots: np.ndarray) -> np.ndarray:
        """(k*3,) columns of the landmarks in ``slots`` inside x."""
        return (self._nv + 3 * slots[:, None] + _AR3).ravel()

    def stacked_measurement(self, ids: np.ndarray) -> tuple[np.ndarray, FloatArray, FloatArray]:
        """Stacked observation model of the mapped/known landmarks ``ids`` (eq. 34 and 40).

        Args:
            ids: (k,) landmark ids; all must be mapped (or in the known map).

        Returns:
            ``(cols, h, H)``: ``cols`` (d,) the columns of x the model depends on
            (``[s, m_κ]``, d = 9 + 3k; only s in ``known_map`` mode), ``h`` (3k,) the predicted
            measurements (α, β, δ per landmark) and ``H`` (3k, d) = ``∂h/∂x[cols]``.
        """
        lookup = self._known_index if self.known_map else self._slot
        rows = np.array([lookup[int(i)] for i in np.asarray(ids).reshape(-1).tolist()], dtype=int)
        lms, cols = self._observed(rows)
        return (cols, *self._model_at(lms, cols.shape[0]))

    def _observed(self, rows: np.ndarray) -> tuple[FloatArray, np.ndarray]:
        """Positions (k, 3) of the map rows/slots ``rows`` and the columns ``[s, m_κ]`` of x."""
        if self.known_map:
            return self._known_pos[rows], self._pose_cols
        lm_cols = self._landmark_cols(rows)
        return self._x[lm_cols].reshape(-1, 3), np.concatenate((self._pose_cols, lm_cols))

    def _model_at(self, lms: FloatArray, d: int) -> tuple[FloatArray, FloatArray]:
        """Predicted measurements (3k,) and H (3k, d) of landmarks ``lms`` (k, 3)."""
        x = self._x
        pos, eul = x[0:3], x[6:9]
        C = dcm_from_euler(eul)
        k = lms.shape[0]
        H_pos, H_eul, H_lm = lidar_jacobians(pos, eul, C, lms)
        h = lidar_measure(pos, C, lms).ravel()
        H = np.zeros((3 * k, d))
        H3 = H.reshape(k, 3, d)
        H3[:, :, 0:3] = H_pos
        H3[:, :, 6:9] = H_eul
        if d > POSE_DIM:
            ar = np.arange(k)
            H3[ar[:, None, None], _AR3[None, :, None], (9 + 3 * ar)[:, None, None] + _AR3] = H_lm
        return h, H

    def update(self, scan: LidarScan) -> None:
        """Correct with one LiDAR scan, then register new landmarks (eq. 37–53).

        Observed mapped landmarks are gated one by one on their 3-DOF NIS
        ``ν_iᵀ S_ii⁻¹ ν_i`` (rejections counted in ``n_rejected``); the accepted ones form one
        stacked update over the columns ``idx = [s, m_κ]`` only: ``PHᵀ = P[:, idx] Hᵀ``,
        ``S = H P[idx, idx] Hᵀ + R`` (eq. 38), Cholesky ``S = L Lᵀ``, ``W = PHᵀ L⁻ᵀ``,
        ``x += W L⁻¹ ν`` (eq. 42, azimuth/elevation innovations wrapped) and
        ``P -= W Wᵀ`` (= ``K S Kᵀ``, eq. 43). If S is not positive definite or the result
        would be non-finite, the update is skipped and the ``diverged`` flag set. Unmapped
        landmarks are then registered (skipped in ``known_map`` mode, where ids outside the
        known map are ignored).

        Args:
            scan: Scan with sorted ``ids`` (k,), ``meas`` (k, 3) = (α rad, β rad, δ m) and
                ``sigma`` (3,) noise stds. An empty scan is a no-op.

        Raises:
            ValueError: If the measurements are not a finite (k, 3) array.
        """
        ids_list = [int(i) for i in np.asarray(scan.ids).reshape(-1).tolist()]
        k = len(ids_list)
        if k == 0:
            return
        meas = np.asarray(scan.meas, dtype=float)
        if meas.shape != (k, 3) or not np.isfinite(meas).all():
            raise ValueError(f"update: scan.meas must be a finite ({k}, 3) array")
        r_diag = np.asarray(scan.sigma, dtype=float).reshape(3) ** 2
        lookup = self._known_index if self.known_map else self._slot
        found = [lookup.get(i, -1) for i in ids_list]
        obs = [j for j in range(k) if found[j] >= 0]
        if obs:
            lms, cols = self._observed(np.array([found[j] for j in obs], dtype=int))
            self._update_mapped(meas[obs], lms, cols, r_diag)
        if not self.known_map and len(obs) < k:
            new = [j for j in range(k) if found[j] < 0]
            self._register([ids_list[j] for j in new], meas[new], r_diag)

    def _update_mapped(
        self, meas: FloatArray, lms: FloatArray, cols: np.ndarray, r_diag: FloatArray
    ) -> None:
        """Gated stacked update with landmarks ``lms`` (k, 3) observed as ``meas`` (k, 3)."""
        k = lms.shape[0]
        n = self._n
        x, P = self._x, self._P
        h, H = self._model_at(lms, cols.shape[0])
        nu = measurement_residual(meas, h.reshape(k, 3))  # (k, 3), α and β wrapped
        PHt = P[:n, cols] @ H.T  # (n, 3k): P[:, idx] Hᵀ
        S = H @ PHt[cols]
        S.flat[:: 3 * k + 1] += np.tile(r_diag, k)
        ar = np.arange(k)
        blocks = S.reshape(k, 3, k, 3)[ar, :, ar, :]  # (k, 3, 3) per-landmark S_ii
        try:
            sol = np.linalg.solve(blocks, nu[:, :, None])[:, :, 0]
        except np.linalg.LinAlgError:
            self._diverged = True
            return
        nis_each = np.einsum("ki,ki->k", nu, sol)
        if not np.isfinite(nis_each).all():
            self._diverged = True
            return
        keep = nis_each <= self.gate_threshold
        n_keep = int(keep.sum())
        self._n_rejected_last = k - n_keep
        self._n_rejected += k - n_keep
        if n_keep == 0:
            return
        nu_v = nu.ravel()
        if n_keep < k:
            keep3 = np.repeat(keep, 3)
            S = S[np.ix_(keep3, keep3)]
            PHt = PHt[:, keep3]
            nu_v = nu_v[keep3]
        try:
            L = np.linalg.cholesky(S)
        except np.linalg.LinAlgError:
            self._diverged = True
            return
        # numpy-only linear algebra here: mixing numpy's and scipy's OpenBLAS thread pools in
        # this hot path was measured to cost milliseconds per call on a 2-core machine.
        Li = np.linalg.inv(L)  # L⁻¹, (m, m)
        W = PHt @ Li.T  # (n, m) = P Hᵀ L⁻ᵀ, so K = W L⁻¹
        z = Li @ nu_v  # L⁻¹ ν
        nis = float(z @ z)
        dx = W @ z  # K ν
        new_diag = P[:n, :n].diagonal() - np.einsum("ij,ij->i", W, W)
        if (
            not math.isfinite(nis)
            or not math.isfinite(float(dx.sum()))
            or float(new_diag.min()) < -1e-9
        ):
            self._diverged = True
            return
        x[:n] += dx
        P[:n, :n] -= W @ W.T  # K S Kᵀ (eq. 43); numpy computes W Wᵀ exactly symmetric (syrk)
        x[6] = _wrap(float(x[6]))
        x[8] = _wrap(float(x[8]))
        self._nis = nis
        self._nis_dof = 3 * n_keep
        self._n_updates += 1

    # ------------------------------------------------------------------ registration
    def _register(self, ids: list[int], meas: FloatArray, r_diag: FloatArray) -> None:
        """Augment x and P with new landmarks (seed 001 eq. 44–53).

        ``l = g(ŝ⁺, y) = ρ + C_NB ϱ(y)``, ``P_ll = G_s P_ss G_sᵀ + G_y R G_yᵀ``,
        ``P_lx = G_s [P_ss P_sm]``. All new landmarks of the scan are added in one block;
        this equals registering them one at a time (eq. 46–53), since registration leaves ŝ
        unchanged and the cross-covariance of two new landmarks is ``G_si P_ss G_sjᵀ`` either
        way.
        """
        kn = len(ids)
        n = self._n
        self._ensure_capacity(n + 3 * kn)
        x, P = self._x, self._P
        pos, eul = x[0:3], x[6:9]
        C = dcm_from_euler(eul)
        lms = lidar_inverse(pos, C, meas)
        G_eul, G_meas = inverse_jacobians(eul, C, meas)
        Gs = np.zeros((3 * kn, POSE_DIM))
        Gs3 = Gs.reshape(kn, 3, POSE_DIM)
        Gs3[:, :, 0:3] = _I3
        Gs3[:, :, 6:9] = G_eul
        Plx = Gs @ P[:POSE_DIM, :n]  # (3kn, n), eq. 50
        Pll = Plx[:, :POSE_DIM] @ Gs.T  # G_s P_ss G_sᵀ
        ar = np.arange(kn)
        Pll.reshape(kn, 3, kn, 3)[ar, :, ar, :] += (G_meas * r_diag) @ G_meas.transpose(0, 2, 1)
        Pll = 0.5 * (Pll + Pll.T)
        if not (np.isfinite(lms).all() and np.isfinite(Pll).all() and np.isfinite(Plx).all()):
            self._diverged = True
            return
        end = n + 3 * kn
        P[n:end, :n] = Plx
        P[:n, n:end] = Plx.T
        P[n:end, n:end] = Pll
        x[n:end] = lms.ravel()
        for j, i in enumerate(ids):
            self._slot[i] = len(self._ids) + j
        self._ids.extend(ids)
        self._n = end

    # ------------------------------------------------------------------ output
    def estimate(self) -> Estimate:
        """Snapshot of the belief (copies).

        Returns:
            :class:`Estimate` with the pose mean, ``pose_cov`` (9, 9) over (ρ, v_B, Λ),
            ``rates`` = last gyro minus bias estimate, landmarks sorted by id (in ``known_map``
            mode the known map with zero covariance), biases (``accel_bias = (0, 0, b̂_az)``)
            when estimated, and ``diagnostics``: ``nis`` (last stacked NIS, NaN before the
            first update), ``nis_dof``, ``n_rejected`` (cumulative), ``n_rejected_last``,
            ``n_updates``, ``n_mapped``, ``diverged`` (1.0 once a step had to be skipped).
        """
        x, P, nv = self._x, self._P, self._nv
        C = dcm_from_euler(x[6:9])
        if self.known_map:
            order = np.argsort(self._known_ids, kind="stable")
            lm_ids = self._known_ids[order]
            lm_means = self._known_pos[order]
            lm_covs = np.zeros((lm_ids.shape[0], 3, 3))
        else:
            ids = np.array(self._ids, dtype=int)
            order = np.argsort(ids, kind="stable")
            lm_ids = ids[order]
            idx = nv + 3 * order
            lm_means = x[idx[:, None] + _AR3]
            lm_covs = P[idx[:, None, None] + _AR3[:, None], idx[:, None, None] + _AR3]
        gyro_bias = accel_bias = None
        if self.estimate_imu_bias:
            gyro_bias = x[9:12].copy()
            accel_bias = np.array([0.0, 0.0, x[12]])
        return Estimate(
            position=x[0:3].copy(),
            vel_body=x[3:6].copy(),
            vel_inertial=C @ x[3:6],
            euler=x[6:9].copy(),
            rates=self._rates.copy(),
            pose_cov=P[:POSE_DIM, :POSE_DIM].copy(),
            landmark_ids=lm_ids,
            landmark_means=lm_means,
            landmark_covs=lm_covs,
            accel_bias=accel_bias,
            gyro_bias=gyro_bias,
            diagnostics={
                "nis": float(self._nis),
                "nis_dof": float(self._nis_dof),
                "n_rejected": float(self._n_rejected),
                "n_rejected_last": float(self._n_rejected_last),
                "n_updates": float(self._n_updates),
                "n_mapped": float(len(self._ids)),
                "diverged": 1.0 if self._diverged else 0.0,
            },
        )

    # ------------------------------------------------------------------ testing/debugging
    def full_state(self) -> tuple[FloatArray, FloatArray, np.ndarray]:
        """Copies of the total mean x (n,), covariance P (n, n) and the mapped ids in slot
        order (landmark j occupies ``x[nv + 3j : nv + 3j + 3]``, nv = 9 or 13 with biases)."""
        n = self._n
        return self._x[:n].copy(), self._P[:n, :n].copy(), np.array(self._ids, dtype=int)

    def set_full_state(self, x: FloatArray, P: FloatArray) -> None:
        """Overwrite the total mean and covariance (same size n as :meth:`full_state`).

        Raises:
            ValueError: On a shape mismatch or non-finite values.
        """
        n = self._n
        x = np.asarray(x, dtype=float)
        P = np.asarray(P, dtype=float)
        if x.shape != (n,) or P.shape != (n, n):
            raise ValueError(f"set_full_state: expected x ({n},) and P ({n}, {n})")
        if not (np.isfinite(x).all() and np.isfinite(P).all()):
            raise ValueError("set_full_state: x and P must be finite")
        self._x[:n] = x
        self._P[:n, :n] = P
