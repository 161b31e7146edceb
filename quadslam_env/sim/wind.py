"""The wind of B lanes: a steady wind plus Dryden gusts, one filter state per lane.

docs/design.md §2, §9 and docs/physics.md "Wind". The equations (the Dryden filters, discretised
exactly over the control period) are :mod:`quadslam_env.models.wind`; this class holds each
lane's filter state and generator. The wind is held over a control step (the vehicle kernel
reads :attr:`WindBatch.velocity`) and advanced once per step, after the step. With
``wind.inform_estimator`` the estimator gets that wind before it predicts the step
(:meth:`WindBatch.inform`).

Random stream per lane (the contract with the single env): with turbulence, the gusts'
generator is spawned at reset from the lane's world child (the generator that draws the
landmarks; spawning takes nothing from its stream, so the landmarks, the other sensors and
every later episode draw exactly what they draw without wind); from it ``standard_normal(5)``
for the stationary initial filter state, then per step ``standard_normal(5)``, drawn ahead in
blocks of :attr:`WindBatch.BLOCK` steps (the same sequence). A steady wind draws nothing.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike

from quadslam_env.config.world import WindConfig
from quadslam_env.estimation.protocol import TakesWind
from quadslam_env.models.wind import (
    GUST_STATES,
    dryden_filter,
    dryden_low_altitude,
    dryden_step_lanes,
    gust_axes,
)
from quadslam_env.sim.sensor_lanes import lane_generators, lane_indices
from quadslam_env.types import FloatArray

WIND_KEYS = ("wind_n_mps", "wind_e_mps", "wind_d_mps")
"""``info`` terms of the wind a step flew in (at reset: the first step's), N frame, m/s."""


class WindBatch:
    """Steady wind plus optional Dryden turbulence for B lanes (or still air: every method a
    no-op, one check per call).

    Args:
        cfg: Wind settings.
        period_s: Control period T in s (the wind's update and hold interval).
        num_lanes: B.

    Attributes:
        velocity: (B, 3) wind in N (m/s) over the current step, updated in place; ``None`` in
            still air (``cfg.enabled`` false).
        state: (B, 5) Dryden filter states (zeros without turbulence).
        turbulent: Whether the Dryden gusts are on.
        scale: (B,) factor on each lane's whole wind for its episode (domain randomisation,
            :meth:`set_scales`; 1 otherwise).
    """

    BLOCK = 64
    """Steps of normals drawn ahead per lane and generator call."""

    def __init__(self, cfg: WindConfig, period_s: float, num_lanes: int) -> None:
        b = int(num_lanes)
        self.num_lanes = b
        self.steady = np.array(cfg.steady_mps, dtype=float)
        self.velocity: FloatArray | None = np.tile(self.steady, (b, 1)) if cfg.enabled else None
        self.state = np.zeros((b, GUST_STATES))
        self.turbulent = cfg.turbulence == "dryden"
        sigma, length = dryden_low_altitude(cfg.altitude_m, cfg.w20_mps)
        speed = cfg.speed_mps if self.turbulent else 1.0  # unused without turbulence
        self.filter = dryden_filter(sigma, length, speed, period_s)
        self._out_map = gust_axes(self.steady) @ self.filter.output  # state -> gust in N
        self._rngs: list[np.random.Generator | None] = [None] * b
        self._noise = np.zeros((b, self.BLOCK, GUST_STATES))
        self._cursor = np.full(b, self.BLOCK)
        self._lane_ids = np.arange(b)
        self.scale = np.ones(b)  # (B,) per-lane factors on the whole wind (set_scales)
        self.informs = cfg.inform_estimator  # the estimator is told the wind (inform)
        self._still_air = np.zeros((b, 3))

    def set_scales(self, lanes: ArrayLike, scale: ArrayLike) -> None:
        """Scale the whole wind (steady part and gust) of ``lanes`` (k,) by ``scale`` (k,) for
        the episode :meth:`reset` just started (domain randomisation; no-op in still air)."""
        if self.velocity is None:
            return
        idx = lane_indices(lanes)
        s = np.asarray(scale, dtype=float)
        self.scale[idx] = s
        if self.turbulent:  # reset wrote steady + gust
            self.velocity[idx] *= s[:, None]
        else:
            self.velocity[idx] = self.steady * s[:, None]

    def reset(self, lanes: ArrayLike, parents: Sequence[np.random.Generator]) -> None:
        """Start the ``lanes`` (k,) with a stationary gust.

        Args:
            lanes: (k,) lane indices.
            parents: (k,) generators the lanes' gust generators are spawned from (the world
                children, module docstring); untouched without turbulence.
        """
        idx = lane_indices(lanes)
        if self.velocity is None or not self.turbulent:
            return
        chol = self.filter.stationary
        for lane, parent in zip(idx.tolist(), parents, strict=True):
            rng = parent.spawn(1)[0]
            self.state[lane] = chol @ rng.standard_normal(GUST_STATES)
            self.velocity[lane] = self.steady + self._out_map @ self.state[lane]
            self._rngs[lane] = rng
        self._cursor[idx] = self.BLOCK  # the pre-drawn block belonged to the old generator

    def advance(self, active: np.ndarray) -> None:
        """Advance the gust of the ``active`` (B,) lanes by one period (no-op without gusts)."""
        if self.velocity is None or not self.turbulent:
            return
        lanes = self._lane_ids if active.all() else np.flatnonzero(active)
        empty = lanes[self._cursor[lanes] >= self.BLOCK]
        if empty.size:
            gens = lane_generators(self._rngs, empty, "WindBatch")
            for lane, rng in zip(empty.tolist(), gens, strict=True):
                rng.standard_normal(out=self._noise[lane])  # (BLOCK, 5) in place, no copy
            self._cursor[empty] = 0
        f = self.filter
        dryden_step_lanes(
            lanes, self._cursor, self._noise, self.state, f.phi, f.chol, self._out_map,
            self.steady, self.scale, self.velocity,
        )  # fmt: skip

    @property
    def current(self) -> FloatArray:
        """(B, 3) the wind in N (m/s) held now: :attr:`velocity`, or zeros in still air."""
        return self._still_air if self.velocity is None else self.velocity

    def inform(self, estimator: object) -> None:
        """With ``wind.inform_estimator``, give ``estimator`` (which then
        :class:`~quadslam_env.estimation.protocol.TakesWind`) the wind of the step it is about
        to predict (:attr:`velocity`; zeros in still air, where the air-relative drag is then
        the simulator's still-air drag, quadratic part included)."""
        if not self.informs:
            return
        if not isinstance(estimator, TakesWind):  # its class said models_drag = True
            raise TypeError(f"{type(estimator).__name__} says models_drag but has no set_wind")
        estimator.set_wind(self.current)

    def info(self) -> dict[str, FloatArray]:
        """The ``info`` terms :data:`WIND_KEYS` of the current wind, (B,) copies each; none in
        still air (terms are defined where they apply)."""
        if self.velocity is None:
            return {}
        return {key: self.velocity[:, j].copy() for j, key in enumerate(WIND_KEYS)}
