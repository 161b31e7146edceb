"""The estimated state of a FastSLAM filter as typed containers (docs/design.md §5).

:class:`ParticleState` holds what the particle filter estimates: the particles, their weights,
their landmark EKFs, the landmark bookkeeping and the SLAM gauge. The filter class
(:class:`~.particles.FastSLAMBase`) owns one. The functions of the other modules take the
state or its arrays, update in place only the arrays they document, and return their results
(log-likelihoods, NIS, the number of tempered stages, :class:`~.associate.ScanAssociation`);
the filter applies those to the weights, the loss-of-lock check and its diagnostics. Shapes:
N particles, L landmark slots.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from estimators.fastslam.associate import ParticleMaps
from estimators.fastslam.resampling import ess_of
from quadslam_env.types import STATE_DIM, FloatArray


@dataclass
class LandmarkSlots:
    """The id → slot map of labeled landmarks, shared by every particle (known association
    or a known map; docs/design.md §3). Slots are appended in the order ids are first seen.

    Attributes:
        slot: Landmark id → its slot on the L axis of :attr:`ParticleState.mu`.
        ids: (L,) the id of each slot.
        ids_sorted: (L,) int the ids in ascending order (the estimate's order).
        order: (L,) int the slots in ascending id order (``ids[order] == ids_sorted``).
    """

    slot: dict[int, int] = field(default_factory=dict)
    ids: list[int] = field(default_factory=list)
    ids_sorted: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=int))
    order: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=int))

    def add(self, ids: np.ndarray) -> None:
        """Give each of ``ids`` (k,) int, not yet mapped, the next slot."""
        for lid in ids.tolist():
            self.slot[int(lid)] = len(self.ids)
            self.ids.append(int(lid))
        ids_all = np.array(self.ids, dtype=int)
        self.order = np.argsort(ids_all, kind="stable")
        self.ids_sorted = ids_all[self.order]

    def of(self, ids: np.ndarray) -> np.ndarray:
        """(k,) int the slot of each of ``ids`` (k,) int, -1 for an id not mapped yet."""
        return np.array([self.slot.get(i, -1) for i in ids.tolist()])


@dataclass
class ParticleState:
    """Particles, weights, landmark EKFs and map bookkeeping of one FastSLAM filter.

    Every per-particle array is resampled with fancy indexing (fresh copies, no shared views).
    :attr:`w` and :attr:`ess` follow :attr:`logw`: assign log-weights with :meth:`set_logw`,
    or update all three together (:func:`~.resampling.apply_log_likelihood`).

    Attributes:
        x: (N, 12) particle states ``x^D = (ρ [m, N], v_B [m/s, B], Λ [rad, 3-2-1 Euler
            N→B], ω [rad/s, B])``.
        logw: (N,) normalised log-weights.
        w: (N,) normalised weights ``exp(logw)``.
        ess: Effective sample size ``1 / Σ w_i²`` of :attr:`w`, in particles.
        mu: (N, L, 3) landmark means ``μ_j^i`` in N, m (labeled scans: slots of
            :attr:`slots`; unlabeled scans: particle i's landmarks are slots
            ``0 … maps.size[i] − 1`` and L is a capacity).
        sigma: (N, L, 3, 3) their covariances ``Σ_j^i`` in m².
        lineage: (N,) int index of each particle's ancestor among the particles drawn at
            reset.
        slots: The labeled landmarks' id → slot map.
        maps: The per-particle maps of unlabeled scans (:class:`~.associate.ParticleMaps`),
            ``None`` until the first unlabeled scan.
        known_map: Known-map mode (the landmarks were given at reset).
        gauge: SLAM with ``anchor_gauge`` (:mod:`.gauge`): ``(G, ρ_a)``, the gauge prior
            G (4, 4) of ``(ρ [m, N], ψ [rad])`` in m², m·rad, rad² and its rotation centre
            ρ_a (3,) in N, m; else ``None``.
        time: Filter time in s (the sum of the prediction periods since reset).
    """

    x: FloatArray
    logw: FloatArray
    w: FloatArray
    ess: float
    mu: FloatArray
    sigma: FloatArray
    lineage: np.ndarray
    slots: LandmarkSlots = field(default_factory=LandmarkSlots)
    maps: ParticleMaps | None = None
    known_map: bool = False
    gauge: tuple[FloatArray, FloatArray] | None = None
    time: float = 0.0

    @classmethod
    def empty(cls, n: int) -> ParticleState:
        """N particles at the origin with equal weights and no landmarks."""
        logw = np.full(n, -math.log(n))
        w = np.exp(logw)
        return cls(
            x=np.zeros((n, STATE_DIM)),
            logw=logw,
            w=w,
            ess=float(ess_of(w)),
            mu=np.zeros((n, 0, 3)),
            sigma=np.zeros((n, 0, 3, 3)),
            lineage=np.arange(n),
        )

    @property
    def n_particles(self) -> int:
        """N."""
        return int(self.logw.shape[0])

    def set_logw(self, value: FloatArray) -> None:
        """Take new normalised log-weights (N,); :attr:`w` and :attr:`ess` follow."""
        self.logw = np.array(value, dtype=float).reshape(self.n_particles)
        np.exp(self.logw, out=self.w)
        self.ess = float(ess_of(self.w))

    def unlabeled_maps(self) -> ParticleMaps:
        """The per-particle maps of unlabeled scans, made at the first one (known-map mode:
        every particle holds the known landmarks).

        Raises:
            ValueError: An unlabeled scan after labeled ones in SLAM.
        """
        if self.maps is None:
            if self.slots.ids and not self.known_map:
                raise ValueError(
                    "update: an unlabeled scan after labeled ones; a FastSLAM run takes one kind"
                )
            known = np.array(self.slots.ids, dtype=np.int64) if self.known_map else None
            self.maps = ParticleMaps(self.n_particles, known)
        return self.maps


@dataclass
class BiasKFState:
    """The IMU bias/drift Kalman filter of every particle of the dynamic filter (seed 000
    eq. 8–12, Table 4; :mod:`.bias_kf`).

    The bias subsystem is linear with the same ``A, H, Q, R`` for every particle; the particles
    differ only in the innovation, which enters the means but not the covariance, so one
    covariance serves all of them.

    Attributes:
        xb: (N, 12) each particle's bias mean ``x̂^B = (b0_a [m/s², B], b0_ω [rad/s, B],
            b1_a [m/s², B], b1_ω [rad/s, B])`` (constant biases b0, Gauss–Markov drifts b1).
        P: (12, 12) their shared covariance, in the squared units of ``x̂^B``.
    """

    xb: FloatArray
    P: FloatArray
