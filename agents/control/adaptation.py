"""Thrust adaptation of the baselines with integral action (LQI, SE(3)): the feed-forward
scaled by the thrust ratio that the vertical integral measures.

**The error it removes.** Both controllers turn a commanded thrust acceleration ``u_p`` (m/s²,
reference-heading frame H, NED-like: ``u_p,z < 0`` points the thrust up) into the thrust of the
nominal mass, ``f_T = m_nom ‖u_p‖`` (the LQI's inverse map; SE(3)'s ``f = −m_nom A · R e3``). A
vehicle of mass ``m`` whose actuators produce ``k f_T`` (``randomize.thrust_scale`` k) then gets
the specific force ``k f_T / m = ‖u_p‖ / r`` along the commanded axis, with the thrust ratio

    r = m / (k m_nom),

so that (attitude on its command) ``ρ̈ = g n3 + u_p / r``: the vehicle achieves ``1/r`` of every
commanded acceleration. Write the command as ``u_p = a − g n3 + c``, with ``a = ρ̈_d − K_r r̃``
(plus the drag compensation, :mod:`agents.control.drag`) the designed demand and ``c`` the
integral command (the LQI's ``−K_ξ ξ``, SE(3)'s ``−k_I e_I``). Tracking (``r̃ = 0``) needs
``u_p = r (ρ̈_d − g n3)``, i.e. ``c = (r − 1)(ρ̈_d − g n3)``: constant vertically on a level
reference (the gravity deficit ``c_z = −(r − 1) g``), but horizontally it must follow
``(r − 1) ρ̈_d,xy``, which on the figure-8 turns all the time; the integral lags behind it and
the lag is a tracking error (docs/controllers.md "Thrust adaptation" has the figures).

**The estimate.** The steady vertical integral command is the gravity deficit, so

    r̂ = 1 − c_z / g,    clipped to :data:`RATIO_BOUNDS`,

from what the controller already has (its own integral of the observation's error, never the
truth), per lane. With ``thrust_adaptation=True`` the feed-forward is scaled by it, the
feedback, the gravity term and the integral are not:

    u_p = r̂ ρ̈_d − K_r r̃ − g n3 + c,

so the controller flies the observation whose reference acceleration is ``r̂ ρ̈_d``
(:func:`scale_reference`; the drag compensation, a feed-forward too, is scaled likewise).
Vertically, at the loop's equilibrium (``r̃ = 0``), ``u_p,z = r (ρ̈_d,z − g)`` reads
``r̂ ρ̈_d,z − g + c_z = r̂ (ρ̈_d,z − g)`` (insert ``r̂``): so ``r̂ = r`` on any reference, not
only in hover, and then ``c_xy = (r − r̂) ρ̈_d,xy = 0``: the horizontal integrals carry only
horizontal disturbances. This is the certainty-equivalence form of adaptive control (Åström &
Wittenmark, *Adaptive Control*, 2nd ed. 1995, ch. 3: the controller designed for the known
plant, its parameter replaced by its estimate), and the form of PX4's position controller,
which turns its acceleration set-point into thrust with the hover thrust over g
(``PositionControl::_accelerationControl``: ``collective_thrust = acc_sp_z · T_h/g − T_h``),
``T_h`` from its hover-thrust estimator, a one-state Kalman filter; here the integral is the
estimator. The integral is not scaled because it is the estimate: scaling it would make
``r̂ (c_z − g) = −r g`` with ``r̂ = 1 − c_z/g``, i.e. ``r̂ = √r``.

**Why the feed-forward only.** The feedback keeps its design: about the equilibrium the loop
is the one without adaptation (per axis ``r s³ + k_d s² + k_p s + k_ξ``, Hurwitz iff
``k_ξ r < k_p k_d``: the shipped gains for every ``r < 6.2``), the vertical integral's gain
times ``1 − ρ̈_d,z / g`` (1 on a level reference) and the horizontal axes driven by it through
``δr̂ ρ̈_d,xy`` (a cascade, no loop closed): the ratio enters only through ``ρ̈_d``, a fraction
of a m/s² on the figure-8. Scaling
the feedback too would restore the designed gains at the equilibrium, but during a transient
the integral holds the transient's own error (a take-off climb's, frozen by the conditional
integration while an actuator saturates), so the feedback would be scaled by a ratio that is
not yet the vehicle's, exactly when the loop is far from the reference; flown on EKF-SLAM that
lost an episode in the climb (docs/controllers.md "Thrust adaptation"). The integrators are the
controllers' own, unchanged, so every equilibrium still has ``ξ̇ = r̃ = 0`` on each integrated
axis: a constant disturbance leaves no steady-state error (final-value theorem); ``r̂`` only
moves the equilibrium's ``c``. With a zero integral ``r̂ = 1.0`` exactly and the command is the
one without adaptation, bit for bit.

``r̂`` lumps every constant vertical acceleration error into the thrust ratio: a vertical drag,
the cosine lost to an attitude error, an estimator's vertical bias. On the truth it is ``r``.

**Bounds.** ``r̂`` is clipped to [0.5, 2] (:data:`RATIO_BOUNDS`): a factor of two either way,
beyond the randomised scenario's ``r ∈ [0.8/1.1, 1.2/0.9] = [0.73, 1.33]``; an integral that
reads more (a climb's transient, a wound-up lane) cannot scale the demand without limit, and a
clipped ``r̂`` still leaves zero steady-state error (the integral supplies the rest).
"""

from __future__ import annotations

import numpy as np

from quadslam_env.episode.observation import BASE_LAYOUT
from quadslam_env.types import GRAVITY, FloatArray

RATIO_BOUNDS = (0.5, 2.0)
"""Smallest and largest estimated thrust ratio ``r̂ = m_eff / m_nom`` (module docstring)."""


def _block(name: str) -> slice:
    """The entries of the base observation block ``name`` (:data:`BASE_LAYOUT`)."""
    start = 0
    for block, size in BASE_LAYOUT:
        if block == name:
            return slice(start, start + size)
        start += size
    raise KeyError(name)


ACC_REF = _block("acc_ref")
"""The observation's reference acceleration ``C3(ψ_d)ᵀ ρ̈_d`` (heading frame, m/s²)."""


def thrust_ratio(vertical_command: FloatArray) -> FloatArray:
    """The estimated thrust ratio ``r̂ = 1 − c_z / g`` clipped to :data:`RATIO_BOUNDS`.

    Args:
        vertical_command: (n,) the integral's command on the vertical axis ``c_z``, m/s²
            (NED-like: negative asks for more thrust, a vehicle heavier than the model).

    Returns:
        (n,) ``r̂`` (1.0 exactly where ``c_z`` is 0).
    """
    lo, hi = RATIO_BOUNDS
    return np.clip(1.0 - np.asarray(vertical_command, dtype=float) / GRAVITY, lo, hi)


def scale_reference(obs: FloatArray, ratio: FloatArray) -> FloatArray:
    """The observations the adapted controller flies: ``obs`` with its reference acceleration
    (:data:`ACC_REF`) scaled by each lane's ``r̂``.

    Args:
        obs: (n, obs_dim) observations (the base layout first).
        ratio: (n,) ``r̂`` per lane.

    Returns:
        (n, obs_dim) a copy, ``ρ̈_d`` times ``r̂`` (``r̂ = 1``: ``obs`` bit for bit).
    """
    out = np.array(obs, dtype=float)
    out[:, ACC_REF] *= ratio[:, None]
    return out
