"""Estimators over a leading batch axis of B lanes (docs/design.md §9), and the one-lane bridge.

The simulation core (:mod:`quadslam_env.core`) steps B independent episodes ("lanes") in
lockstep. It talks to its estimator through :class:`BatchEstimator`: arrays in, arrays out, with
a lane mask wherever lanes differ (a lane that scans this step, a lane that is being reset).
Landmark identities inside the core are the indices ``0 … L-1`` of the lane's landmark array,
so landmark outputs are arrays indexed by id, padded to a capacity ``Lmax`` with a mask.

Estimators that have a native batched implementation register it with
:func:`register_batch`; every other estimator (FastSLAM, a user's own) runs through
:class:`LaneLoop`, a Python loop over B scalar :class:`~estimators.base.Estimator` objects.
"""

from __future__ import annotations

import importlib
import importlib.util
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from estimators.base import Estimate, Estimator, make
from quadslam_env.measurements import Control, ImuSample, LidarScan
from quadslam_env.models.jit import kernel
from quadslam_env.types import POSE_DIM, FloatArray

IntArray = np.ndarray
KnownMaps = Sequence[tuple[np.ndarray, FloatArray]] | None


@dataclass
class BatchEstimate:
    """The belief of B lanes (views into the estimator's buffers: read, don't keep).

    Attributes:
        position: (B, 3) ρ̂ in N, m.
        vel_body: (B, 3) v̂ in B, m/s.
        vel_inertial: (B, 3) ``C_NB(Λ̂) v̂`` in N, m/s.
        euler: (B, 3) Λ̂ = (φ̂, θ̂, ψ̂) in rad.
        rates: (B, 3) ω̂ in B, rad/s.
        pose_cov: (B, 9, 9) covariance of (ρ, v_B, Λ), or ``None`` (the oracle).
        landmark_means: (B, Lmax, 3) estimated landmark positions by id, m (rows of unmapped
            ids are undefined).
        landmark_mapped: (B, Lmax) bool, which ids the lane has mapped (or knows).
        accel_bias: (B, 3) estimated accelerometer bias in m/s², or ``None``.
        gyro_bias: (B, 3) estimated gyro bias in rad/s, or ``None``.
        diagnostics: name → (B,) float array (``nis``, ``ess``, ``diverged``, …; NaN where a
            lane has no value).
    """

    position: FloatArray
    vel_body: FloatArray
    vel_inertial: FloatArray
    euler: FloatArray
    rates: FloatArray
    pose_cov: FloatArray | None
    landmark_means: FloatArray
    landmark_mapped: np.ndarray
    accel_bias: FloatArray | None = None
    gyro_bias: FloatArray | None = None
    diagnostics: dict[str, FloatArray] = field(default_factory=dict)


class BatchEstimator(Protocol):
    """What the simulation core needs from an estimator of B lanes.

    Every method acts on the lanes it is told about and leaves the other lanes' state
    untouched, so lanes of one batch may be at different times of different episodes.
    """

    num_lanes: int
    uses_truth: bool

    def reset_lanes(
        self,
        lanes: IntArray,
        mean0: FloatArray,
        cov0: FloatArray,
        rngs: Sequence[np.random.Generator],
        known_landmarks: KnownMaps = None,
    ) -> None:
        """Start new episodes in ``lanes`` (k,) from means (k, 12) and covariances (k, 12, 12).

        ``rngs[j]`` is lane ``lanes[j]``'s only source of randomness; ``known_landmarks[j]`` is
        ``(ids (L,), positions (L, 3))`` in known-map mode, else ``None``.
        """

    def predict(
        self,
        t: FloatArray,
        accel: FloatArray,
        gyro: FloatArray,
        accel_sigma: float,
        gyro_sigma: float,
        thrust: FloatArray,
        torque: FloatArray,
        dt: float,
        active: np.ndarray,
    ) -> None:
        """Propagate the ``active`` (B,) lanes over ``dt`` s with one IMU sample each.

        ``t`` (B,) sample times in s; ``accel``/``gyro`` (B, 3) measured specific force (m/s²)
        and rates (rad/s) in B, held over ``dt``; ``accel_sigma``/``gyro_sigma`` the white-noise
        std of that input per step of ``dt``, ``ND/√dt`` (the per-sample std when the IMU
        samples every ``dt``; with an IMU slower than the control, the held sample's std
        scaled so that the steps between two samples add up its variance:
        :mod:`quadslam_env.imu_replay`); ``thrust`` (B,) N and ``torque`` (B, 3) N·m applied.
        """

    def update(
        self,
        t: FloatArray,
        lanes: IntArray,
        visible: np.ndarray,
        meas: FloatArray,
        sigma: FloatArray,
    ) -> None:
        """Correct ``lanes`` (k,) with their scans: ``visible`` (B, Lmax) bool marks the
        returned landmark ids, ``meas`` (B, Lmax, 3) their (α rad, β rad, δ m); ``sigma`` (3,)."""

    # Estimators that set ``associates_unlabeled = True`` (``lidar.association: unknown``)
    # also implement ``update_unlabeled(t, lanes, count (B,), returns (B, R, 3), sigma)``:
    # the returns of lane b are ``returns[b, :count[b]]``, unlabeled and in any order; and
    # ``last_association`` (B, R) int: the label (index into ``landmark_means``) each return
    # was paired with, -1 for none. A scalar :class:`~estimators.base.Estimator` gets a
    # :class:`LidarScan` with ``ids=None`` and exposes ``last_association`` (k,).

    def estimate(self) -> BatchEstimate:
        """The belief of every lane."""

    def lane_estimate(self, lane: int) -> Estimate:
        """A frozen :class:`Estimate` (copies) of one lane, with landmark covariances."""


_BATCH_REGISTRY: dict[str, Callable[..., BatchEstimator]] = {}
# Modules that register a native batched estimator, imported on first use.
_BATCH_MODULES: dict[str, str] = {
    "oracle": "estimators.oracle",
    "ekf_slam": "estimators.ekf",
}


def register_batch(
    name: str,
) -> Callable[[Callable[..., BatchEstimator]], Callable[..., BatchEstimator]]:
    """Class decorator: ``make_batch(name, …)`` builds this native batched estimator."""

    def deco(cls: Callable[..., BatchEstimator]) -> Callable[..., BatchEstimator]:
        _BATCH_REGISTRY[name] = cls
        return cls

    return deco


def make_batch(name: str, num_lanes: int, landmark_capacity: int, **cfg: Any) -> BatchEstimator:
    """Build the estimator ``name`` for ``num_lanes`` lanes.

    A native batched class is used where one is registered; otherwise :class:`LaneLoop`
    runs ``num_lanes`` scalar estimators built by :func:`estimators.make`.

    Args:
        name: Estimator name (see :func:`estimators.available`).
        num_lanes: Number of lanes B ≥ 1.
        landmark_capacity: Lmax, an upper bound on the landmark ids the lanes will see (the
            estimator may grow beyond it when a reset brings a larger map).
        **cfg: Settings of the estimator (``vehicle=`` and ``estimator.params``).

    Raises:
        ValueError: Unknown name or invalid settings (from the estimator).
    """
    if name not in _BATCH_REGISTRY and name in _BATCH_MODULES:
        module = _BATCH_MODULES[name]
        if importlib.util.find_spec(module) is not None:  # else: run the scalar one in a loop
            importlib.import_module(module)
    if name in _BATCH_REGISTRY:
        return _BATCH_REGISTRY[name](
            num_lanes=num_lanes, landmark_capacity=landmark_capacity, **cfg
        )
    return LaneLoop([make(name, **cfg) for _ in range(num_lanes)], landmark_capacity)


class LaneLoop:
    """A :class:`BatchEstimator` over B scalar estimators, one per lane (a Python loop).

    This is how estimators without a batched implementation (FastSLAM, plug-ins) run in the
    vector env; its cost is the scalar estimator's times B plus the per-lane conversion of
    samples, scans and snapshots.

    Args:
        estimators: The B scalar estimators.
        landmark_capacity: Initial Lmax of the landmark output arrays (grows as needed).
    """

    def __init__(self, estimators: Sequence[Estimator], landmark_capacity: int) -> None:
        self.lanes = list(estimators)
        self.num_lanes = len(self.lanes)
        check_memory = getattr(self.lanes[0], "check_memory", None)
        if check_memory is not None:  # the filters of the whole batch, before they grow
            check_memory(self.num_lanes, landmark_capacity)
        self.uses_truth = bool(getattr(self.lanes[0], "uses_truth", False))
        b = self.num_lanes
        self._estimates: list[Estimate | None] = [None] * b
        self._out = _empty_batch(b, max(landmark_capacity, 0))
        self.last_association = np.zeros((b, 0), dtype=np.int64)
        """(B, R) int the scalar estimators' labels of their last unlabeled scans' returns."""

    def reset_lanes(
        self,
        lanes: IntArray,
        mean0: FloatArray,
        cov0: FloatArray,
        rngs: Sequence[np.random.Generator],
        known_landmarks: KnownMaps = None,
    ) -> None:
        """Reset each listed lane's scalar estimator (see :class:`BatchEstimator`)."""
        for j, lane in enumerate(np.asarray(lanes).tolist()):
            known = None if known_landmarks is None else known_landmarks[j]
            self.lanes[lane].reset(mean0[j], cov0[j], rngs[j], known_landmarks=known)
            self._estimates[lane] = None

    def predict(
        self,
        t: FloatArray,
        accel: FloatArray,
        gyro: FloatArray,
        accel_sigma: float,
        gyro_sigma: float,
        thrust: FloatArray,
        torque: FloatArray,
        dt: float,
        active: np.ndarray,
    ) -> None:
        """Call each active lane's ``predict`` with its :class:`ImuSample` and :class:`Control`."""
        for lane in np.flatnonzero(active).tolist():
            imu = ImuSample(
                t=float(t[lane]),
                accel=accel[lane].copy(),
                gyro=gyro[lane].copy(),
                accel_sigma=accel_sigma,
                gyro_sigma=gyro_sigma,
            )
            control = Control(thrust=float(thrust[lane]), torque=torque[lane].copy())
            self.lanes[lane].predict(imu, control, dt)
            self._estimates[lane] = None

    def update(
        self,
        t: FloatArray,
        lanes: IntArray,
        visible: np.ndarray,
        meas: FloatArray,
        sigma: FloatArray,
    ) -> None:
        """Call each listed lane's ``update`` with its :class:`LidarScan` (ids ascending)."""
        for lane in np.asarray(lanes).tolist():
            ids = np.flatnonzero(visible[lane])
            scan = LidarScan(t=float(t[lane]), ids=ids, meas=meas[lane, ids], sigma=sigma)
            self.lanes[lane].update(scan)
            self._estimates[lane] = None

    @property
    def associates_unlabeled(self) -> bool:
        """Whether the scalar estimators accept unlabeled scans (unknown association)."""
        return bool(getattr(self.lanes[0], "associates_unlabeled", False))

    def update_unlabeled(
        self,
        t: FloatArray,
        lanes: IntArray,
        count: np.ndarray,
        returns: FloatArray,
        sigma: FloatArray,
    ) -> None:
        """Call each listed lane's ``update`` with an unlabeled :class:`LidarScan`
        (``ids=None``) and collect its ``last_association`` (k,) into :attr:`last_association`."""
        width = returns.shape[1]
        if self.last_association.shape[1] < width:
            self.last_association = np.full((self.num_lanes, width), -1, dtype=np.int64)
        for lane in np.asarray(lanes).tolist():
            k = int(count[lane])
            scan = LidarScan(t=float(t[lane]), ids=None, meas=returns[lane, :k].copy(), sigma=sigma)
            est = self.lanes[lane]
            est.update(scan)
            self.last_association[lane] = -1
            self.last_association[lane, :k] = getattr(est, "last_association", -1)
            self._estimates[lane] = None

    def set_truth(self, states: FloatArray, landmarks: FloatArray, counts: np.ndarray) -> None:
        """Feed the truth to estimators that use it (the oracle run as scalar objects)."""
        for lane, est in enumerate(self.lanes):
            n = int(counts[lane])
            est.set_truth(states[lane], np.arange(n), landmarks[lane, :n])  # type: ignore[attr-defined]
            self._estimates[lane] = None

    def lane_particles(self, lane: int) -> FloatArray | None:
        """(N, 3) particle positions of lane ``lane`` (m), or ``None`` when its estimator has
        no particles (for display)."""
        positions = getattr(self.lanes[lane], "particle_positions", None)
        return None if positions is None else positions()

    def lane_estimate(self, lane: int) -> Estimate:
        """The scalar estimator's own snapshot (cached until the lane changes)."""
        est = self._estimates[lane]
        if est is None:
            est = self.lanes[lane].estimate()
            self._estimates[lane] = est
        return est

    def estimate(self) -> BatchEstimate:
        """Stack every lane's :class:`Estimate` into the batch arrays."""
        snaps = [self.lane_estimate(lane) for lane in range(self.num_lanes)]
        need = _id_width(snaps)
        if need > self._out.landmark_means.shape[1]:
            self._out = _empty_batch(self.num_lanes, need)
        fill_batch(self._out, snaps)
        return self._out


def _id_width(snaps: Sequence[Estimate]) -> int:
    """Landmark-array width that holds every id of the snapshots (largest id + 1)."""
    # max of a list: a tenth of ndarray.max()'s cost on the few ids a snapshot holds
    return max((max(s.landmark_ids.tolist()) + 1 for s in snaps if s.landmark_ids.size), default=0)


def _empty_batch(num_lanes: int, capacity: int) -> BatchEstimate:
    b = num_lanes
    return BatchEstimate(
        position=np.zeros((b, 3)),
        vel_body=np.zeros((b, 3)),
        vel_inertial=np.zeros((b, 3)),
        euler=np.zeros((b, 3)),
        rates=np.zeros((b, 3)),
        pose_cov=np.zeros((b, POSE_DIM, POSE_DIM)),
        landmark_means=np.zeros((b, capacity, 3)),
        landmark_mapped=np.zeros((b, capacity), dtype=bool),
    )


def fill_batch(out: BatchEstimate, snaps: Sequence[Estimate]) -> None:
    """Write the scalar snapshots ``snaps`` (one per lane, in lane order) into ``out``.

    Optional parts (covariance, biases, diagnostics) follow the snapshots: ``pose_cov`` and
    the biases become ``None`` when the first lane has none; a diagnostic missing in a lane is
    NaN there.
    """
    b = len(snaps)
    if snaps[0].pose_cov is None:
        out.pose_cov = None
    elif out.pose_cov is None:
        out.pose_cov = np.zeros((b, POSE_DIM, POSE_DIM))
    # Reused between calls (the batch is a view: read, don't keep); zeroed like new arrays.
    for name in ("accel_bias", "gyro_bias"):
        if getattr(snaps[0], name) is None:
            setattr(out, name, None)
        elif getattr(out, name) is None:
            setattr(out, name, np.zeros((b, 3)))
        else:
            getattr(out, name)[:] = 0.0
    keys = list(snaps[0].diagnostics)
    if b > 1:
        keys = sorted({k for s in snaps for k in s.diagnostics})
    if list(out.diagnostics) != keys:
        out.diagnostics = {k: np.full(b, np.nan) for k in keys}
    elif b > 1:
        for column in out.diagnostics.values():
            column[:] = np.nan
    out.landmark_mapped[:] = False
    for lane, s in enumerate(snaps):
        out.position[lane] = s.position
        out.vel_body[lane] = s.vel_body
        out.vel_inertial[lane] = s.vel_inertial
        out.euler[lane] = s.euler
        out.rates[lane] = s.rates
        if out.pose_cov is not None and s.pose_cov is not None:
            out.pose_cov[lane] = s.pose_cov
        if out.accel_bias is not None and s.accel_bias is not None:
            out.accel_bias[lane] = s.accel_bias
        if out.gyro_bias is not None and s.gyro_bias is not None:
            out.gyro_bias[lane] = s.gyro_bias
        if s.landmark_ids.size:
            out.landmark_means[lane, s.landmark_ids] = s.landmark_means
            out.landmark_mapped[lane, s.landmark_ids] = True
        diagnostics = out.diagnostics
        for k, v in s.diagnostics.items():
            diagnostics[k][lane] = v


def batch_from_estimates(snaps: Sequence[Estimate]) -> BatchEstimate:
    """A fresh :class:`BatchEstimate` holding the scalar snapshots ``snaps``."""
    out = _empty_batch(len(snaps), _id_width(snaps))
    fill_batch(out, snaps)
    return out


HEALTH_PROBLEMS = (
    "",
    "estimator reported divergence",
    "non-finite position",
    "non-finite vel_body",
    "non-finite euler",
    "non-finite rates",
    "non-finite landmark means",
    "non-finite pose covariance",
    "asymmetric pose covariance",
    "pose covariance not positive semi-definite (negative variance)",
    "pose covariance not positive semi-definite (correlation beyond ±1)",
    "pose covariance trace above episode.max_cov_trace",
)
"""What :func:`health_codes` codes mean (0: healthy)."""

PSD_TOLERANCE = 1e-6
"""Round-off allowed by the positive-semi-definiteness checks, relative to the largest pose
variance: a variance below ``-tol·scale`` or a 2×2 minor ``P_ij² − P_ii P_jj`` above
``tol·P_ii P_jj + (tol·scale)²`` is not round-off."""


_NO_COV = np.zeros((1, 1, 1))


@kernel
def _covariance_code(P: FloatArray, tol: float, max_trace: float) -> int:
    """Codes 7–11 (0: healthy) of one pose covariance (n, n), in one pass over its entries.

    The first failed check in :data:`HEALTH_PROBLEMS` order wins: non-finite, asymmetric,
    negative variance, correlation beyond ±1 (a 2×2 minor beyond round-off), trace too large.
    """
    n = P.shape[0]
    scale = 1e-12
    trace = 0.0
    for i in range(n):
        scale = max(scale, abs(P[i, i]))
        trace += P[i, i]
    nonfinite = asymmetric = negative = correlated = False
    for i in range(n):
        pii = P[i, i]
        nonfinite = nonfinite or not math.isfinite(pii)
        negative = negative or pii < -tol * scale
        for j in range(i):
            pij, pji = P[i, j], P[j, i]
            nonfinite = nonfinite or not (math.isfinite(pij) and math.isfinite(pji))
            asymmetric = asymmetric or abs(pij - pji) > 1e-6 * scale
            prod = max(pii, 0.0) * max(P[j, j], 0.0)
            correlated = correlated or pij * pij - prod > tol * prod + (tol * scale) ** 2
    if nonfinite:
        return 7
    if asymmetric:
        return 8
    if negative:
        return 9
    if correlated:
        return 10
    return 11 if trace > max_trace else 0


@kernel
def _health_codes(
    diverged: FloatArray,
    position: FloatArray,
    vel_body: FloatArray,
    euler: FloatArray,
    rates: FloatArray,
    lm_means: FloatArray,
    lm_mapped: np.ndarray,
    cov: FloatArray,
    has_cov: bool,
    max_trace: float,
    out: np.ndarray,
) -> None:
    """Fill ``out`` (B,) with the first failed check's index into :data:`HEALTH_PROBLEMS`."""
    tol = PSD_TOLERANCE
    for b in range(out.shape[0]):
        code = 1 if diverged[b] > 0.0 else 0
        for i in range(3):  # codes 2-5: position, vel_body, euler, rates (first failure wins)
            if code == 0 and not math.isfinite(position[b, i]):
                code = 2
        for i in range(3):
            if code == 0 and not math.isfinite(vel_body[b, i]):
                code = 3
        for i in range(3):
            if code == 0 and not math.isfinite(euler[b, i]):
                code = 4
        for i in range(3):
            if code == 0 and not math.isfinite(rates[b, i]):
                code = 5
        for j in range(lm_mapped.shape[1]):
            for i in range(3):
                if code == 0 and lm_mapped[b, j] and not math.isfinite(lm_means[b, j, i]):
                    code = 6
        if code == 0 and has_cov:
            code = _covariance_code(cov[b], tol, max_trace)
        out[b] = code


def health_codes(est: BatchEstimate, max_cov_trace: float = math.inf) -> np.ndarray:
    """What is wrong with each lane's belief, as (B,) indices into :data:`HEALTH_PROBLEMS`.

    Checks (docs/design.md §7), first failure wins: the estimator's own ``diverged`` flag, a finite
    mean (pose, rates and mapped landmarks), a finite and symmetric pose covariance with no
    negative variance and no correlation beyond ±1 (beyond :data:`PSD_TOLERANCE` round-off),
    and a pose-covariance trace (over ρ m², v m²/s², Λ rad²) at most ``max_cov_trace``. The
    full positive-semi-definiteness test is the Cholesky factorisation that the NEES needs
    anyway (:func:`estimators.metrics.cholesky_nees` returns inf on failure), so it is not
    repeated. Every estimator is checked the same way (the oracle has no covariance).

    Args:
        est: The belief of B lanes.
        max_cov_trace: Largest healthy trace of the 9×9 pose covariance (``inf``: no limit).
    """
    b = est.position.shape[0]
    out = np.zeros(b, dtype=np.int64)
    diverged = est.diagnostics.get("diverged")
    cov = est.pose_cov
    _health_codes(
        np.zeros(b) if diverged is None else np.asarray(diverged, dtype=float),
        est.position,
        est.vel_body,
        est.euler,
        est.rates,
        est.landmark_means,
        est.landmark_mapped,
        _NO_COV if cov is None else cov,
        cov is not None,
        float(max_cov_trace),
        out,
    )
    return out


def health_problem(est: Estimate, max_cov_trace: float = math.inf) -> str | None:
    """What is wrong with one scalar snapshot (see :func:`health_codes`); ``None`` if healthy."""
    code = int(health_codes(batch_from_estimates([est]), max_cov_trace)[0])
    return HEALTH_PROBLEMS[code] or None


def position_std(est: BatchEstimate) -> FloatArray:
    """The estimator's own position uncertainty √trace(P_ρ) (B,) in m: 0 without a covariance
    (the oracle) and where the trace is not finite (such a lane ends as diverged on this step,
    see :func:`health_codes`)."""
    cov = est.pose_cov
    if cov is None:
        return np.zeros(est.position.shape[0])
    trace = cov[:, 0, 0] + cov[:, 1, 1] + cov[:, 2, 2]
    return np.where(np.isfinite(trace), np.sqrt(np.maximum(trace, 0.0)), 0.0)
