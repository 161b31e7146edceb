"""Actions: validation and the map from normalised actions to thrust and torque (docs/design.md §4).

``thrust_torque`` maps ``a0`` to thrust in ``[0, max_thrust]`` and ``a1..a3`` to
``±max_torque``; ``thrust_rates`` maps ``a1..a3`` to body-rate commands ``±max_rate`` tracked by
an inner P loop ``τ = J K (ω_cmd - ω̂)`` on the estimate's rates (the gyro minus the estimated
bias for EKF-SLAM); ``rotor_thrust`` (a vehicle with rotors) maps ``a0..a3`` to the four rotors'
thrusts ``(a_i + 1)/2 · T_max`` and returns their wrench through the mixer
(:mod:`quadslam_env.models.rotors`), which the vehicle inverts exactly back to the same rotor
thrusts (every action type works on a vehicle with rotors: the vehicle applies the inverse mixer
to any thrust and torque). Works on B lanes at once.
"""

from __future__ import annotations

import math
import numbers
from typing import Any

import numpy as np

from quadslam_env.config.scenario import ActionConfig
from quadslam_env.models.jit import kernel
from quadslam_env.models.params import VehicleParams
from quadslam_env.types import FloatArray

ACTION_DIM = 4
_FAST_DTYPES = (np.dtype(np.float32), np.dtype(np.float64))


@kernel
def _clip_lanes(action: np.ndarray, out: FloatArray) -> bool:
    """``out`` (B, 4) = ``action`` (B, 4) as float64 clipped to [-1, 1]; False (``out``
    incomplete) at the first non-finite entry."""
    for i in range(action.shape[0]):
        for j in range(action.shape[1]):
            v = float(action[i, j])
            if not math.isfinite(v):
                return False
            out[i, j] = min(max(v, -1.0), 1.0)
    return True


@kernel
def _thrust_torque(
    action: FloatArray, max_thrust: float, max_torque: FloatArray, thrust: FloatArray,
    torque: FloatArray,
) -> None:  # fmt: skip
    """Thrust (B,) ``(a0 + 1)/2 · max_thrust`` (both action modes) and the ``thrust_torque``
    torque (B, 3) ``a1..3 · max_torque``."""
    for i in range(action.shape[0]):
        thrust[i] = 0.5 * (action[i, 0] + 1.0) * max_thrust
        for j in range(3):
            torque[i, j] = action[i, j + 1] * max_torque[j]


class ActionError(ValueError):
    """An action of the wrong shape, type or with non-finite entries."""


def validate_actions(action: Any, num_lanes: int | None, dim: int = ACTION_DIM) -> FloatArray:
    """Check and clip an action to [-1, 1].

    Args:
        action: The action: shape (dim,) for the scalar env (``num_lanes=None``), (B, dim) for
            a vector env of ``num_lanes`` lanes.
        num_lanes: B, or ``None`` for a single action.
        dim: Components of one action (4, or 5 with the heading channel).

    Returns:
        (B, dim) float actions clipped to [-1, 1] (B = 1 for a single action).

    Raises:
        ActionError: Wrong type or shape, or non-finite entries (naming the lanes).
    """
    single = num_lanes is None
    want = (dim,) if single else (num_lanes, dim)
    if (
        type(action) is np.ndarray
        and action.dtype in _FAST_DTYPES
        and action.shape == want
        and action.flags.c_contiguous
    ):  # the common case in one pass; anything else (or a non-finite entry) below
        out = np.empty((action.size // dim, dim))
        if _clip_lanes(action.reshape(-1, dim), out):
            return out
    name = "action" if single else "actions"
    allowed = f"{dim} finite numbers in [-1, 1]" if single else f"shape {want}, finite, in [-1, 1]"
    arr = _real_array(action, name, allowed)
    if arr.shape != want:
        raise ActionError(f"{name}: got shape {arr.shape}; allowed: shape {want} in [-1, 1]")
    finite = np.isfinite(arr)
    if not finite.all():
        if single:
            raise ActionError(f"action: got non-finite values {arr.tolist()}; allowed: {allowed}")
        lanes = np.flatnonzero(~finite.all(axis=1)).tolist()
        raise ActionError(
            f"actions: non-finite values in lane(s) {lanes}; allowed: {allowed}; no lane was "
            "stepped"
        )
    return np.clip(arr.reshape(-1, dim), -1.0, 1.0)


def _real_array(action: Any, name: str, allowed: str) -> FloatArray:
    """``action`` as a float array, if it holds real numbers only: a numeric dtype (bool,
    integer, float), or objects that are all real numbers. Strings and bytes (even of
    digits), complex numbers, dates, other objects and masked arrays are refused.

    Raises:
        ActionError: Naming ``name``, what it got (on one line) and ``allowed``.
    """
    if isinstance(action, np.ma.MaskedArray):  # a masked entry has no value to act on
        raise ActionError(
            f"{name}: got a masked array; allowed: {allowed}, as a plain array or list"
        )
    try:
        arr = np.asarray(action)
        kind = arr.dtype.kind
        if kind not in "biuf" and not (kind == "O" and all(map(_is_real, arr.flat))):
            raise TypeError(f"dtype {arr.dtype}")
        return arr.astype(float, copy=False)
    except (TypeError, ValueError, OverflowError) as exc:
        shown = " ".join(repr(action).split())  # one line, whatever the repr
        shown = shown if len(shown) <= 120 else f"{shown[:117]}..."
        raise ActionError(
            f"{name}: got {shown}; allowed: {allowed} (real numbers, not strings or bytes)"
        ) from exc


def _is_real(value: Any) -> bool:
    """True for a real number (Python or NumPy: bool, int, float), not for strings or bytes."""
    return isinstance(value, numbers.Real)


class ActionMap:
    """Normalised actions → physical inputs for one vehicle and action mode.

    Args:
        cfg: Action settings (mode, rate limits and inner-loop gains).
        params: Vehicle parameters (thrust and torque limits, inertia; the rotors for
            ``rotor_thrust``).

    Raises:
        ValueError: ``rotor_thrust`` on a vehicle without rotors (the scenario check raises the
            :class:`~quadslam_env.config.ConfigError` first).
    """

    def __init__(self, cfg: ActionConfig, params: VehicleParams) -> None:
        self.mode = cfg.mode
        self.params = params
        self.max_rate = np.radians(cfg.max_rate_dps)
        self.rate_gain = np.array(cfg.rate_gain_per_s)
        self._max_thrust = float(params.max_thrust)
        self._max_torque = np.array(params.max_torque, dtype=float)
        self.dim = cfg.dim
        self.max_heading_rate = math.radians(cfg.max_heading_rate_dps)
        self.hover_action = np.zeros(self.dim)
        self.hover_action[0] = 2.0 * params.hover_thrust / params.max_thrust - 1.0
        if self.mode == "rotor_thrust":
            rotors = params.rotors
            if rotors is None:
                raise ValueError(
                    f"action.mode: got 'rotor_thrust' on vehicle {params.name!r} without "
                    "rotors; allowed: 'thrust_torque' or 'thrust_rates'"
                )
            self._rotor_max = rotors.thrust_max
            self._mixer_t = np.array(rotors.mixer.T)
            self.hover_action[:ACTION_DIM] = 2.0 * params.hover_thrust / (4 * rotors.thrust_max) - 1

    def heading_rate(self, action: FloatArray) -> FloatArray:
        """The commanded reference heading rate ψ̇_d (B,) in rad/s of actions (B, 5)."""
        return action[:, ACTION_DIM] * self.max_heading_rate

    def inputs(self, action: FloatArray, rates_hat: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Thrust (B,) N and torque (B, 3) N·m for actions (B, ≥ 4) and estimated rates (B, 3)
        (a heading channel, column 4, is the reference's: :meth:`heading_rate`)."""
        b = action.shape[0]
        thrust, torque = np.empty(b), np.empty((b, 3))
        act = np.ascontiguousarray(action[:, :ACTION_DIM], dtype=float)
        _thrust_torque(act, self._max_thrust, self._max_torque, thrust, torque)
        if self.mode == "thrust_torque":
            return thrust, torque
        if self.mode == "rotor_thrust":
            wrench = (0.5 * (act + 1.0) * self._rotor_max) @ self._mixer_t
            return np.ascontiguousarray(wrench[:, 0]), np.ascontiguousarray(wrench[:, 1:])
        rates_cmd = act[:, 1:] * self.max_rate  # thrust_rates: the same thrust, a rate loop
        return thrust, (self.rate_gain * (rates_cmd - rates_hat)) @ self.params.inertia.T


class ActionDelay:
    """Actions applied ``action.delay_steps`` = d control steps after the agent gives them
    (docs/timing.md "Latency"): each lane's last d actions in a ring, slot (own step) % d, so a
    lane keeps its own phase after an autoreset.

    A reset fills a lane's ring with the hover action (:attr:`ActionMap.hover_action`): the
    command that holds the nominal vehicle still, which flight software sends before the
    first command of its controller arrives (a zero action would be zero thrust: a drop).

    Args:
        delay_steps: d ≥ 1.
        num_lanes: B.
        hover: (dim,) the hover action.
    """

    def __init__(self, delay_steps: int, num_lanes: int, hover: FloatArray) -> None:
        self.hover = np.asarray(hover, dtype=float)
        self._ring = np.zeros((int(delay_steps), int(num_lanes), self.hover.shape[0]))

    def reset(self, lanes: np.ndarray) -> None:
        """Fill ``lanes`` (k,) with hover: the commands in flight belong to the old episode."""
        self._ring[:, lanes] = self.hover

    def apply(self, action: FloatArray, active: np.ndarray, steps: np.ndarray) -> FloatArray:
        """The actions (B, dim) the ``active`` (B,) lanes apply this period (``steps`` (B,) their
        steps since reset, before it): each the one given d of its steps ago; ``action``
        (B, dim) takes its place. Rows of inactive lanes are ``action``'s."""
        ring = self._ring
        lanes = np.flatnonzero(active)
        slots = steps[lanes] % ring.shape[0]
        applied = action.copy()
        applied[lanes] = ring[slots, lanes]
        ring[slots, lanes] = action[lanes]
        return applied
