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
from quadslam_env.models.frames import wrap_angle, wrap_pi
from quadslam_env.models.jit import kernel
from quadslam_env.types import FloatArray

YAW_ERR = 8  # observation index of wrap(ψ̂ − ψ_d)


@kernel
def _aim_lanes(block: FloatArray, half_width: float, aim: FloatArray, found: np.ndarray) -> None:
    """Step 1 of the rule over lanes: the aim ``aim`` (n,) in rad, ``found`` (n,) False where
    nothing is mapped (``aim`` then left as it was).

    Args:
        block: (n, K, 4) nearest-landmark blocks ``(α, β, δ, mask)`` of the observation.
        half_width: Half-width of the window that counts as in view, rad.
        aim: (n,) output, the circular mean of the landmarks in the fullest window (ties: the
            window whose centre needs the smallest turn).
        found: (n,) output, whether the lane has a mapped landmark.
    """
    k = block.shape[1]
    alpha = np.empty(k)
    for b in range(block.shape[0]):
        m = 0
        for i in range(k):
            if block[b, i, 3] > 0.5:
                alpha[m] = block[b, i, 0]
                m += 1
        found[b] = m > 0
        if m == 0:
            continue
        best, best_count = 0, -1
        for c in range(m):  # each mapped landmark as a window's centre, in order
            count = 0
            for i in range(m):
                if abs(wrap_pi(alpha[i] - alpha[c])) <= half_width:
                    count += 1
            if count > best_count or (count == best_count and abs(alpha[c]) < abs(alpha[best])):
                best, best_count = c, count
        sin_sum = cos_sum = 0.0
        for i in range(m):
            if abs(wrap_pi(alpha[i] - alpha[best])) <= half_width:
                sin_sum += math.sin(alpha[i])
                cos_sum += math.cos(alpha[i])
        aim[b] = math.atan2(sin_sum / best_count, cos_sum / best_count)


def aim_azimuth(azimuth: FloatArray, mask: FloatArray, half_width: float) -> float | None:
    """The body-frame azimuth (rad) to point at so that most mapped landmarks are in view.

    One lane of the batched kernel the policy uses.

    Args:
        azimuth: (K,) azimuths α of the nearest mapped landmarks, rad.
        mask: (K,) 1 for a mapped landmark, 0 for padding.
        half_width: Half-width of the window that counts as in view, rad.

    Returns:
        The circular mean of the landmarks in the fullest window (ties: the window whose
        centre needs the smallest turn), or ``None`` when nothing is mapped.
    """
    block = np.zeros((1, len(azimuth), 4))
    block[0, :, 0] = azimuth
    block[0, :, 3] = mask
    aim, found = np.zeros(1), np.zeros(1, dtype=np.bool_)
    _aim_lanes(block, float(half_width), aim, found)
    return float(aim[0]) if found[0] else None


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
        n = obs.shape[0]
        block = np.ascontiguousarray(obs[:, self._block]).reshape(n, -1, 4)
        aim, found = np.zeros(n), np.empty(n, dtype=np.bool_)
        _aim_lanes(block, self._half_width, aim, found)
        rate = self.gain * np.asarray(wrap_angle(aim + obs[:, YAW_ERR]))
        return np.where(found, np.clip(rate / self._max_rate, -1.0, 1.0), self.search_rate)

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
