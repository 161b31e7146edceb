"""A hand-written active-perception baseline: DF-LQR that turns toward the mapped landmarks.

On a scenario with a free heading (``trajectory.yaw_mode: free``, ``action.heading: true``) and
the nearest-landmark observation (``observation.landmarks_nearest``), :class:`LookAtPolicy`
flies DF-LQR on the position reference and steers the reference heading so that as many mapped
landmarks as possible lie inside the LiDAR's azimuth field of view:

1. among the mapped landmarks of the observation (azimuths α_i from the estimated pose), pick
   the window of half-width ``fov − margin`` centred on one of them that holds the most (ties:
   the smallest turn), and aim at the middle of the landmarks inside it;
2. command the heading rate ``ψ̇_d = clip(k (θ + wrap(ψ̂ − ψ_d)), ±ψ̇_max)``, θ being that aim
   relative to the body heading, so ψ_d turns toward ψ̂ + θ; with nothing mapped yet it turns
   at ``search_rate`` of ψ̇_max to look around.

It reads only the observation (the estimate), never the truth.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from agents.control.dflqr import DFLQRPolicy
from quadslam_env.models.frames import wrap_angle
from quadslam_env.types import FloatArray

YAW_ERR = 8  # observation index of wrap(ψ̂ − ψ_d)


def aim_azimuth(azimuth: FloatArray, mask: FloatArray, half_width: float) -> float | None:
    """The body-frame azimuth (rad) to point at so that most mapped landmarks are in view.

    Args:
        azimuth: (K,) azimuths α of the nearest mapped landmarks, rad.
        mask: (K,) 1 for a mapped landmark, 0 for padding.
        half_width: Half-width of the window that counts as in view, rad.

    Returns:
        The circular mean of the landmarks in the fullest window (ties: the window whose
        centre needs the smallest turn), or ``None`` when nothing is mapped.
    """
    alpha = azimuth[mask > 0.5]
    if alpha.size == 0:
        return None
    inside = np.abs(wrap_angle(alpha[None, :] - alpha[:, None])) <= half_width  # (c, i)
    counts = inside.sum(axis=1)
    best = np.flatnonzero(counts == counts.max())
    centre = best[np.argmin(np.abs(alpha[best]))]
    members = alpha[inside[centre]]
    return float(math.atan2(np.sin(members).mean(), np.cos(members).mean()))


class LookAtPolicy:
    """DF-LQR plus the look-at heading rule, with stable-baselines3's ``predict``.

    Args:
        env: A (possibly wrapped) ``QuadSLAMEnv`` or vector env whose scenario has the heading
            channel and ``observation.landmarks_nearest`` > 0.
        gain: k, 1/s.
        margin_deg: Landmarks count as in view up to ``azimuth_fov_deg − margin_deg``.
        search_rate: Heading rate with nothing mapped, as a share of ψ̇_max.

    Raises:
        ValueError: The scenario lacks the heading channel or the landmark observation.
    """

    def __init__(
        self, env: Any, gain: float = 1.5, margin_deg: float = 10.0, search_rate: float = 0.5
    ) -> None:
        base = env.unwrapped
        scenario = base.scenario
        if not scenario.action.heading or not scenario.observation.landmarks_nearest:
            raise ValueError(
                f"scenario {scenario.name!r}: LookAtPolicy needs action.heading: true and "
                "observation.landmarks_nearest > 0"
            )
        self.dflqr = DFLQRPolicy.from_env(env)
        self.action_dim = 5
        offset = 0
        for name, size in base.core.observer.layout:
            if name == "landmarks_nearest":
                break
            offset += size
        self._block = slice(offset, offset + 4 * scenario.observation.landmarks_nearest)
        self._max_rate = math.radians(scenario.action.max_heading_rate_dps)
        self._half_width = math.radians(scenario.lidar.azimuth_fov_deg - margin_deg)
        self.gain = gain
        self.search_rate = search_rate

    def heading_command(self, obs: FloatArray) -> FloatArray:
        """The heading channel a4 (n,) in [-1, 1] for observations (n, obs_dim)."""
        out = np.empty(obs.shape[0])
        for i, o in enumerate(obs):
            block = o[self._block].reshape(-1, 4)
            theta = aim_azimuth(block[:, 0], block[:, 3], self._half_width)
            if theta is None:
                out[i] = self.search_rate
                continue
            rate = self.gain * float(wrap_angle(theta + o[YAW_ERR]))
            out[i] = max(-1.0, min(1.0, rate / self._max_rate))
        return out

    def predict(
        self,
        observation: np.ndarray,
        state: Any = None,
        episode_start: Any = None,
        deterministic: bool = True,
    ) -> tuple[np.ndarray, Any]:
        """SB3-style ``predict``: (obs_dim,) or (n, obs_dim) → float32 actions (…, 5)."""
        obs = np.asarray(observation, dtype=float)
        batch = obs[None, :] if obs.ndim == 1 else obs
        act, _ = self.dflqr.predict(batch)
        act[:, 4] = self.heading_command(batch)
        return (act[0] if obs.ndim == 1 else act), state
