"""Feed-forward of the estimated drag for the baselines with integral action (LQI, SE(3)).

In the wind the drag on the air-relative velocity is a slowly varying acceleration the LQI's
and SE(3)'s integrals otherwise have to build up (docs/controllers.md "Drag feed-forward"). With
``drag_feedforward=True`` the controller adds to the acceleration it asks of the thrust
(``u_p`` of the LQI, ``A`` of SE(3), both in the reference-heading frame H) the compensation

    c = −a_D,    a_D = C_HB d(v̂_a),    d(v_a) = −μ v_a − c_q ∘ (‖v_a‖ v_a),

where ``d`` is the simulator's drag per unit mass on the body axes
(:func:`quadslam_env.models.rigid_body.aero_specific_force` with no thrust on unit mass: the
same kernel the truth and EKF-SLAM's wind states use), ``μ`` and ``c_q`` the nominal vehicle's
linear (1/s) and quadratic (1/m) drag, ``v̂_a`` the estimated velocity relative to the
estimated wind (the observation's ``air_velocity`` block, B frame, m/s) and
``C_HB = C3(ψ̂ − ψ_d) C2(θ̂) C1(φ̂)`` the estimated attitude in H (the observation's
``roll_pitch`` and ``yaw_err``). The thrust then supplies ``u_p − a_D``, so that with the
drag added the vehicle gets ``u_p``.

The controller reads only its observation, so the env must append the air velocity
(``observation.air_velocity: true``, which needs an estimator that estimates the wind: EKF-SLAM
with ``estimator.params.wind: estimate``); :func:`feedforward_kwargs` finds the block's column
when the controller is built from an env.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from quadslam_env.episode.observation import observation_layout
from quadslam_env.models.frames import dcm_from_trig
from quadslam_env.models.jit import kernel
from quadslam_env.models.params import VehicleParams
from quadslam_env.models.rigid_body import aero_specific_force
from quadslam_env.schema import ConfigError
from quadslam_env.types import FloatArray

AIR_BLOCK = "air_velocity"
"""The observation block (:func:`quadslam_env.episode.observation.observation_layout`) the
feed-forward reads: ``v̂_a`` (3,) in B, m/s."""


@kernel
def drag_compensation_lanes(
    obs: FloatArray, column: int, mu: float, cq: FloatArray, out: FloatArray
) -> None:
    """The compensation ``c = −C_HB d(v̂_a)`` (module docstring) of n lanes.

    Args:
        obs: (n, ≥ column + 3) observations: the base layout, ``v̂_a`` at ``column``.
        column: First entry of the air-velocity block.
        mu: Linear drag in 1/s. cq: (3,) quadratic drag per body axis in 1/m.
        out: (n, 3) receives ``c`` in the heading frame, m/s².
    """
    q = (cq[0], cq[1], cq[2])
    for b in range(obs.shape[0]):
        o = obs[b]
        c = dcm_from_trig(math.cos(o[6]), math.sin(o[6]), math.cos(o[7]), math.sin(o[7]),
                          math.cos(o[8]), math.sin(o[8]))  # fmt: skip
        d = aero_specific_force(o[column], o[column + 1], o[column + 2], 0.0, 1.0, mu, q)
        for i in range(3):
            out[b, i] = -(c[3 * i] * d[0] + c[3 * i + 1] * d[1] + c[3 * i + 2] * d[2])


class DragFeedforward:
    """The drag compensation of one controller (module docstring).

    Args:
        vehicle: Nominal vehicle parameters (``drag`` μ in 1/s, ``drag_quadratic`` c_q (3,)
            in 1/m).
        column: First observation entry of the air-velocity block, or ``None`` when the
            observation has none (refused).
        name: The controller's name, for the errors (``lqi``, ``se3``).

    Raises:
        ConfigError: ``column`` is ``None`` or negative.
    """

    def __init__(self, vehicle: VehicleParams, column: int | None, name: str) -> None:
        if column is None or isinstance(column, bool) or not isinstance(column, int | np.integer):
            raise ConfigError(
                f"{name}.drag_feedforward: got true with air_velocity_index = {column!r} (no "
                "estimated air velocity in the observation); allowed: false, or an env with "
                "observation.air_velocity: true, whose estimator estimates the wind (ekf_slam "
                "with estimator.params.wind: estimate)"
            )
        if column < 0:
            raise ConfigError(
                f"{name}.air_velocity_index: got {column}; allowed: an observation column >= 0"
            )
        self.column = int(column)
        self.mu = float(vehicle.drag)
        self.cq = np.array(vehicle.drag_quadratic, dtype=float).reshape(3)
        self.name = name

    def compensation(self, obs: FloatArray) -> FloatArray:
        """(n, 3) compensation ``c`` in the heading frame, m/s², for observations (n, obs_dim).

        Raises:
            ValueError: The observations are too short to hold the air-velocity block.
        """
        if obs.shape[1] < self.column + 3:
            raise ValueError(
                f"{self.name}.drag_feedforward: observations of {obs.shape[1]} entries; "
                f"allowed: at least {self.column + 3} (the air velocity at {self.column})"
            )
        out = np.empty((obs.shape[0], 3))
        drag_compensation_lanes(np.ascontiguousarray(obs, dtype=float), self.column, self.mu,
                                self.cq, out)  # fmt: skip
        return out


def check_flag(name: str, value: Any, option: str = "drag_feedforward") -> bool:
    """``value`` of the controller option ``{name}.{option}`` (``drag_feedforward``,
    ``thrust_adaptation``) as a bool.

    Raises:
        ConfigError: ``value`` is not a bool.
    """
    if not isinstance(value, bool | np.bool_):
        raise ConfigError(f"{name}.{option}: got {value!r}; allowed: true or false (a bool)")
    return bool(value)


def air_velocity_column(env: Any) -> int | None:
    """The first column of the air-velocity block in the observation of a (possibly wrapped)
    scalar or vector env, or ``None`` when its scenario has ``observation.air_velocity`` off."""
    start = 0
    for block, size in observation_layout(env.unwrapped.scenario.observation):
        if block == AIR_BLOCK:
            return start
        start += size
    return None


def feedforward_kwargs(env: Any, kwargs: dict[str, Any]) -> dict[str, Any]:
    """``kwargs`` with ``air_velocity_index`` from ``env`` (:func:`air_velocity_column`) when
    they turn ``drag_feedforward`` on and do not give it."""
    if kwargs.get("drag_feedforward") is True and "air_velocity_index" not in kwargs:
        kwargs = {**kwargs, "air_velocity_index": air_velocity_column(env)}
    return kwargs
