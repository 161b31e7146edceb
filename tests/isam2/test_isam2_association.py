"""Unknown data association of the iSAM2 smoother (:mod:`estimators.isam2.associate`): the
truth on an easy case, clutter kept out of the map, the χ² gate, the env, determinism and
failures."""

from __future__ import annotations

import math
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
from conftest import AHEAD

import quadslam_env  # noqa: F401  (registers the env ids)
from agents.control.dflqr import DFLQRPolicy
from estimators.association import chi2_threshold
from estimators.isam2.associate import PosePrediction, ScanAssociation
from estimators.isam2.estimator import Isam2Slam
from estimators.isam2.settings import Isam2Settings
from quadslam_env.estimation.measurements import Control, ImuSample, LidarScan
from quadslam_env.models.frames import dcm_from_euler, wrap_angle
from quadslam_env.models.lidar import lidar_measure
from quadslam_env.types import GRAVITY

gtsam = pytest.importorskip("gtsam")

SIGMA = np.array([np.deg2rad(0.33), np.deg2rad(0.30), 0.1])
HOVER = ImuSample(0.0, np.array([0.0, 0.0, -GRAVITY]), np.zeros(3), 0.03, 1e-3)
NO_CONTROL = Control(0.0, np.zeros(3))


def _start(*filters: Isam2Slam) -> None:
    cov0 = np.diag([1e-3] * 3 + [1e-2] * 3 + [1e-4] * 3 + [1e-6] * 3)
    for f in filters:
        f.reset(np.zeros(12), cov0, np.random.default_rng(0))


def _hover_scans(
    labeled: Isam2Slam, unlabeled: Isam2Slam, scans: int, seed: int = 4
) -> list[tuple[np.ndarray, np.ndarray]]:
    """Hover at the origin among the AHEAD landmarks: 10 IMU samples then one scan, ``scans``
    times; the labeled filter gets ids, the other the same returns shuffled and unlabeled.

    Returns:
        Per scan, ``(order (6,), association (6,))``: the true landmark of each unlabeled
        return and the id the unlabeled filter paired it with.
    """
    rng = np.random.default_rng(seed)
    lms = np.array(AHEAD, dtype=float)
    out = []
    for k in range(scans):
        for _ in range(10):
            for f in (labeled, unlabeled):
                f.predict(HOVER, NO_CONTROL, 0.01)
        meas = lidar_measure(np.zeros(3), dcm_from_euler(np.zeros(3)), lms)
        meas = meas + SIGMA * rng.standard_normal(meas.shape)
        meas[:, :2] = wrap_angle(meas[:, :2])
        order = rng.permutation(len(lms))
        labeled.update(LidarScan(0.1 * k, np.arange(len(lms)), meas, SIGMA))
        unlabeled.update(LidarScan(0.1 * k, None, meas[order], SIGMA))
        out.append((order, unlabeled.last_association.copy()))
    return out


def _truth_of_labels(est: Any) -> dict[int, int]:
    """The estimator's landmark ids → the true landmark nearest to each one's mean."""
    snap = est.estimate()
    lms = np.array(AHEAD, dtype=float)
    return {
        int(i): int(np.argmin(np.linalg.norm(lms - m, axis=1)))
        for i, m in zip(snap.landmark_ids(), snap.mapped_landmarks()[1], strict=True)
    }


@pytest.mark.parametrize("method", ["nn", "jcbb"])
def test_easy_association_is_the_truth_and_matches_known_association(method: str) -> None:
    """Well-separated landmarks (≥ 2.9 m apart, 30× the range noise), every one returned, no
    clutter, a landmark mapped at first sight (M = N = 1) and a gate wide enough for every
    true pairing: every return of every scan is paired with the landmark it came from, and
    the smoother then holds the same factors as with labels (up to the landmarks' names), so
    its estimate is the labeled one up to rounding."""
    wide = {"gate_probability": 1.0 - 1e-9}
    labeled = Isam2Slam()
    unlabeled = Isam2Slam(association=method, confirm_hits=1, confirm_window=1, **wide)
    _start(labeled, unlabeled)
    scans = _hover_scans(labeled, unlabeled, 20)
    truth = _truth_of_labels(unlabeled)
    assert sorted(truth.values()) == list(range(len(AHEAD)))  # a bijection
    for order, assoc in scans:  # exhaustive: every return of every scan
        assert [truth[int(a)] for a in assoc] == order.tolist()
    a, b = labeled.estimate(), unlabeled.estimate()
    np.testing.assert_allclose(b.position[0], a.position[0], rtol=0, atol=1e-9)  # 9e-12 here
    np.testing.assert_allclose(b.pose_cov[0], a.pose_cov[0], rtol=1e-6, atol=1e-12)
    named = [truth[int(i)] for i in b.landmark_ids()]
    np.testing.assert_allclose(
        b.mapped_landmarks()[1], a.mapped_landmarks()[1][named], rtol=0, atol=1e-9
    )


def test_tentative_landmarks_enter_with_their_earlier_sightings() -> None:
    """Default rule (3 hits in 5 scans): the first two scans' returns are tentative (labeled
    -1), the third confirms every landmark, and from then on every return is paired with its
    landmark. A confirmed landmark enters with factors for its two earlier sightings, so after
    20 scans the estimate is the labeled smoother's (same factors, another order of updates):
    3e-9 m apart here, where dropping the earlier sightings leaves them 2.4 cm apart."""
    # Relinearised at every keyframe: with the same factors the two end at the same optimum.
    labeled, unlabeled = Isam2Slam(relinearize_skip=1), Isam2Slam(relinearize_skip=1)
    _start(labeled, unlabeled)
    scans = _hover_scans(labeled, unlabeled, 20, seed=5)
    truth = _truth_of_labels(unlabeled)
    assert sorted(truth.values()) == list(range(len(AHEAD)))
    assert (scans[0][1] == -1).all() and (scans[1][1] == -1).all()
    for order, assoc in scans[2:]:
        assert [truth[int(a)] for a in assoc] == order.tolist()
    a, b = labeled.estimate(), unlabeled.estimate()
    np.testing.assert_allclose(b.position[0], a.position[0], rtol=0, atol=1e-6)
    named = [truth[int(i)] for i in b.landmark_ids()]
    np.testing.assert_allclose(
        b.mapped_landmarks()[1], a.mapped_landmarks()[1][named], rtol=0, atol=1e-6
    )


def test_known_map_returns_are_named_by_the_map_ids() -> None:
    """Localisation against a known map: each unlabeled return is paired with the map id it
    came from (the map's own ids, here 10, 11, …), and a return from no map landmark is
    dropped, never mapped."""
    lms = np.array(AHEAD, dtype=float)
    ids = np.arange(10, 10 + len(lms))
    est = Isam2Slam()
    cov0 = np.diag([1e-3] * 3 + [1e-2] * 3 + [1e-4] * 3 + [1e-6] * 3)
    est.reset(np.zeros(12), cov0, np.random.default_rng(0), known_landmarks=(ids, lms))
    rng = np.random.default_rng(6)
    stray = lidar_measure(np.zeros(3), np.eye(3), np.array([15.0, 5.0, 4.0]))
    for k in range(10):
        for _ in range(10):
            est.predict(HOVER, NO_CONTROL, 0.01)
        meas = lidar_measure(np.zeros(3), np.eye(3), lms) + SIGMA * rng.standard_normal(lms.shape)
        order = rng.permutation(len(lms))
        est.update(LidarScan(0.1 * k, None, np.vstack((meas[order], stray)), SIGMA))
        assert est.last_association.tolist() == [*ids[order].tolist(), -1]
    snap = est.estimate()
    assert snap.landmark_ids().tolist() == ids.tolist() and est.tentative_count == 0
    assert snap.diagnostics["diverged"][0] == 0.0 and np.linalg.norm(snap.position[0]) < 0.05


def test_landmarks_out_of_view_longer_than_the_window_keep_their_variables() -> None:
    """The map leaves the view for 6 s, twenty times a 0.3 s window (60 scans without a
    return), and comes back: the landmarks are still variables of the fixed-lag smoother
    (not marginalised with the poses), the returns pair with them again, and the estimate
    stays with full iSAM2's on the same data (a hover: nearly linear, so marginalising at
    the window's linearisation point costs little: 3e-4 m here). The dead reckoning makes the
    position's variance ~1e8 times the held biases'; a Cholesky factorisation reports an
    indeterminate system there (both smoothers), the default QR does not."""
    lag, full = Isam2Slam(window_s=0.3), Isam2Slam(window_s=None)
    _start(lag, full)
    rng = np.random.default_rng(7)
    lms = np.array(AHEAD, dtype=float)
    empty = LidarScan(0.0, np.zeros(0, dtype=np.int64), np.zeros((0, 3)), SIGMA)
    for k in range(68):
        for _ in range(10):
            for f in (lag, full):
                f.predict(HOVER, NO_CONTROL, 0.01)
        meas = lidar_measure(np.zeros(3), np.eye(3), lms) + SIGMA * rng.standard_normal(lms.shape)
        meas[:, :2] = wrap_angle(meas[:, :2])
        in_view = k < 3 or k >= 63
        scan = LidarScan(0.1 * k, np.arange(len(lms)), meas, SIGMA) if in_view else empty
        for f in (lag, full):
            f.update(scan)
    a, b = lag.estimate(), full.estimate()
    assert a.diagnostics["diverged"][0] == 0.0, lag.last_error
    assert b.diagnostics["diverged"][0] == 0.0, full.last_error
    assert a.landmark_ids().tolist() == list(range(len(lms)))
    np.testing.assert_allclose(a.position[0], b.position[0], rtol=0, atol=2e-3)
    np.testing.assert_allclose(a.mapped_landmarks()[1], b.mapped_landmarks()[1], rtol=0, atol=2e-3)


# ------------------------------------------------------------------ the gate, analytically


def _front(method: str) -> ScanAssociation:
    front = ScanAssociation(Isam2Settings.from_dict({"association": method}))
    front.reset(known=False)
    return front


def _exact(ids: list[int]) -> np.ndarray:
    return np.zeros((6 + 3 * len(ids),) * 2)  # a known pose and landmark: S = R


@pytest.mark.parametrize("method", ["nn", "jcbb"])
def test_gate_pairs_inside_and_drops_or_starts_outside(method: str) -> None:
    """A known pose and landmark make the innovation covariance R = diag(σ²) exactly, so a
    return displaced by c·σ_δ in range has NIS c². Gate χ²₃(0.99) = 11.345, new-landmark gate
    χ²₃(0.9999) = 21.108: c² just inside the gate pairs; just outside it, the return is
    dropped (between the gates: not a new landmark either); beyond the wider gate it starts a
    tentative landmark (not mapped, so labeled -1)."""
    gate, new_gate = chi2_threshold(3, 0.99), chi2_threshold(3, 0.9999)
    assert gate == pytest.approx(11.345, abs=1e-3) and new_gate == pytest.approx(21.108, abs=1e-3)
    landmark = np.array([10.0, 2.0, -1.0])
    pred = PosePrediction(np.eye(3), np.zeros(3), np.zeros((6, 6)), keyframe=1)
    h = lidar_measure(np.zeros(3), np.eye(3), landmark)
    for c2, label, tentative in [
        (0.98 * gate, 7, 0),
        (1.02 * gate, -1, 0),
        (0.98 * new_gate, -1, 0),
        (1.02 * new_gate, -1, 1),
    ]:
        front = _front(method)
        z = h + np.array([0.0, 0.0, math.sqrt(c2) * SIGMA[2]])
        out = front.associate(z[None], SIGMA, pred, {7: landmark}, {7: np.zeros((3, 3))}, _exact)
        assert front.last_association.tolist() == [label], c2
        assert front.tentative_count == tentative, c2
        assert out.ids == ([7] if label == 7 else [])


def test_joint_marginal_is_asked_only_for_landmarks_that_can_gate() -> None:
    """The screen (an upper bound on S) keeps the joint marginal to the landmarks that may
    gate: a landmark 90° away from every return is never part of it."""
    asked: list[list[int]] = []

    def joint(ids: list[int]) -> np.ndarray:
        asked.append(ids)
        return _exact(ids)

    near, far = np.array([10.0, 0.0, 0.0]), np.array([0.0, 10.0, 0.0])
    pred = PosePrediction(np.eye(3), np.zeros(3), 1e-4 * np.eye(6), keyframe=1)
    z = lidar_measure(np.zeros(3), np.eye(3), near)[None]
    front = _front("jcbb")
    covs = {0: 1e-2 * np.eye(3), 1: 1e-2 * np.eye(3)}
    front.associate(z, SIGMA, pred, {0: near, 1: far}, covs, joint)
    assert asked == [[0]] and front.last_association.tolist() == [0]


# ------------------------------------------------------------------ in the env


def _hover_env(overrides: dict[str, Any], steps: int) -> list[dict[str, Any]]:
    layout = {"layout": "explicit", "positions": AHEAD}
    env = gym.make(
        "QuadSLAM-EKF-v0", landmarks=layout, estimator={"name": "isam2", "params": {}}, **overrides
    )
    env.reset(seed=11)
    hover = env.unwrapped.hover_action
    infos = []
    for _ in range(steps):
        _, _, term, trunc, info = env.step(hover)
        assert not (term or trunc), info["termination_reason"]
        infos.append(info)
    env.close()
    return infos


def test_clutter_is_not_confirmed_and_pairings_are_right() -> None:
    """Clutter 5 per scan, detection 0.9, 2 s of hover (20 scans). A false return is uniform
    over the FOV volume in (α, β, δ) (90° × 60° × 48 m ≈ 79 rad²·m); the χ²₃(0.99) gate of two
    sightings is an ellipsoid of (4/3)π (2·11.3)^{3/2} σ_α σ_β σ_δ ≈ 1.4e-3 rad²·m, so a
    tentative landmark started by clutter gets a further hit with probability ≈ 5 · 1.8e-5
    per scan and needs two in four scans: ≈ 5e-8 each, ≈ 1e-5 over the run's ~100. Margin 0:
    no false landmark, and no duplicate of a true one (a return between the gates is dropped)."""
    lidar = {"association": "unknown", "clutter_rate": 5.0, "detection_prob": 0.9}
    infos = _hover_env({"lidar": lidar}, 200)
    last = infos[-1]
    assert last["spurious_landmarks"] == 0
    assert last["est_n_mapped"] <= len(AHEAD)
    assert last["est_n_mapped"] == len(AHEAD)  # and every true landmark is mapped
    associated = sum(i["assoc_n_associated"] for i in infos)
    wrong = sum(i["assoc_n_wrong"] for i in infos)
    clutter = sum(i["assoc_n_returns"] - i["assoc_n_true"] for i in infos)
    print(f"associated {associated:.0f}, wrong {wrong:.0f}, clutter returns {clutter:.0f}")
    assert clutter > 50  # the clutter came
    assert associated > 0.8 * sum(i["assoc_n_true"] for i in infos)
    assert wrong == 0  # precision 1


def _unknown_env(duration: float) -> tuple[Any, DFLQRPolicy]:
    """``paper_ekf_figure8_unknown`` with isam2 for ``duration`` s, and DF-LQR for it."""
    env = gym.make(
        "QuadSLAM-v0",
        scenario="paper_ekf_figure8_unknown",
        estimator_name="isam2",
        episode={"duration_s": duration},
    )
    return env, DFLQRPolicy.from_env(env)


def _fly(seed: int, duration: float) -> tuple[list[dict[str, Any]], Any]:
    env, policy = _unknown_env(duration)
    obs, _ = env.reset(seed=seed)
    infos: list[dict[str, Any]] = []
    done = False
    while not done:
        obs, reward, terminated, truncated, info = env.step(policy.predict(obs)[0])
        assert np.isfinite(obs).all() and np.isfinite(reward)
        assert not terminated, info["termination_reason"]
        infos.append(info)
        done = terminated or truncated
    return infos, env.unwrapped.estimator.lane_estimate(0)


def test_env_flies_the_unknown_association_scenario() -> None:
    """``paper_ekf_figure8_unknown`` (unlabeled, 10% misses, 2 clutter per scan) with isam2:
    3 s of DF-LQR without termination, finite observations, and the association terms in
    ``info`` as for the other estimators."""
    infos, est = _fly(seed=0, duration=3.0)
    assert len(infos) == 300
    for key in ("assoc_n_returns", "assoc_n_associated", "assoc_n_wrong", "assoc_n_true",
                "assoc_n_missed", "assoc_wrong_rate", "assoc_missed_rate",
                "spurious_landmarks"):  # fmt: skip
        assert key in infos[-1], key
    assert infos[-1]["spurious_landmarks"] == 0 and infos[-1]["est_n_mapped"] > 5
    associated = sum(i["assoc_n_associated"] for i in infos)
    assert associated > 50 and sum(i["assoc_n_wrong"] for i in infos) <= 0.01 * associated
    assert est.diagnostics["diverged"] == 0.0 and np.isfinite(est.position).all()
    assert infos[-1]["est_pos_err_m"] < 0.3


def test_two_unknown_association_rollouts_with_the_same_seed_are_identical() -> None:
    runs = [_fly(seed=3, duration=1.5) for _ in range(2)]
    keys = ("est_pos_err_m", "assoc_n_associated", "assoc_n_wrong", "est_n_mapped")
    for key in keys:
        assert [i[key] for i in runs[0][0]] == [i[key] for i in runs[1][0]], key
    np.testing.assert_array_equal(runs[0][1].landmark_means, runs[1][1].landmark_means)
    np.testing.assert_array_equal(runs[0][1].pose_cov, runs[1][1].pose_cov)


def test_keyframe_query_answers_the_association_as_gtsam_would(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """The association reads its joint marginals off the keyframe's query; asking GTSAM anew
    for each (the smoother has not moved since) flies the same 1.5 s to round-off."""
    stored = _fly(seed=3, duration=1.5)

    def query(self: Isam2Slam, nav: list[int], ids: list[int]) -> np.ndarray:
        keys = nav + [self._key("l", i) for i in ids]
        return np.asarray(self._isam.jointMarginalCovariance(keys).fullMatrix())

    monkeypatch.setattr(Isam2Slam, "_joint_marginal", query)
    asked = _fly(seed=3, duration=1.5)
    for key in ("assoc_n_associated", "assoc_n_wrong", "est_n_mapped"):
        assert [i[key] for i in stored[0]] == [i[key] for i in asked[0]], key
    assert sum(i["assoc_n_associated"] for i in stored[0]) > 20
    np.testing.assert_allclose(stored[1].landmark_means, asked[1].landmark_means, atol=1e-9)
    np.testing.assert_allclose(stored[1].pose_cov, asked[1].pose_cov, rtol=1e-7, atol=1e-14)


def test_keyframe_query_sub_blocks_are_gtsams_joint_marginals() -> None:
    """After a keyframe, the joint marginal of the keyframe and any landmarks, in any order,
    read off the keyframe's query equals GTSAM's own query for them."""
    env, policy = _unknown_env(2.0)
    obs, _ = env.reset(seed=1)
    for _ in range(151):  # one step after the keyframe of t = 1.5 s
        obs, *_ = env.step(policy.predict(obs)[0])
    est = env.unwrapped.estimator.lanes[0]
    mapped = sorted(est._lm_means)
    assert len(mapped) >= 4 and est._kf_joint is not None
    ids = [int(i) for i in np.random.default_rng(0).permutation(mapped)[:4]]
    nav = [est._key(c, est.keyframes) for c in "xvb"]
    keys = nav + [est._key("l", i) for i in ids]
    want = np.asarray(est._isam.jointMarginalCovariance(keys).fullMatrix())
    got = est._joint_marginal(nav, ids)
    np.testing.assert_allclose(got, want, rtol=1e-8, atol=1e-12 * np.abs(want).max())


# ------------------------------------------------------------------ bad input


def test_landmark_seen_once_is_no_failure() -> None:
    """M = 1 maps a return at its first sight; seen once and never again, its variable has
    exactly one 3-row factor (determined, not singular): the smoother goes on, finite."""
    est = Isam2Slam(confirm_hits=1, confirm_window=1)
    _start(est)
    for k in range(15):
        for _ in range(10):
            est.predict(HOVER, NO_CONTROL, 0.01)
        meas = np.array([[0.2, -0.1, 12.0]]) if k == 0 else np.zeros((0, 3))
        est.update(LidarScan(0.1 * k, None, meas, SIGMA))
        assert est.last_association.tolist() == ([0] if k == 0 else [])
    snap = est.estimate()
    assert snap.diagnostics["diverged"][0] == 0.0, est.last_error
    assert snap.landmark_ids().tolist() == [0]
    assert np.isfinite(snap.position[0]).all() and np.isfinite(snap.mapped_landmarks()[2]).all()


def test_gtsam_exception_during_association_becomes_divergence() -> None:
    est = Isam2Slam()
    _start(est)
    labeled = Isam2Slam()
    _start(labeled)
    _hover_scans(labeled, est, 4)

    class Broken:
        """The smoother's ISAM2, whose joint marginal fails as GTSAM does when singular."""

        def __getattr__(self, name: str) -> Any:
            raise RuntimeError("Indeterminant linear system detected while working near variable")

    est._isam = Broken()
    est._kf_joint = None  # the association asks the smoother (not the keyframe's query)
    meas = lidar_measure(np.zeros(3), np.eye(3), np.array(AHEAD, dtype=float))
    est.update(LidarScan(0.5, None, meas, SIGMA))
    snap = est.estimate()
    assert snap.diagnostics["diverged"][0] == 1.0 and np.isfinite(snap.position[0]).all()
    assert est.last_error.startswith("RuntimeError: Indeterminant")
    assert est.last_association.tolist() == [-1] * len(AHEAD)
    est.update(LidarScan(0.6, None, meas, SIGMA))  # ignored after the divergence
    assert est.last_association.tolist() == [-1] * len(AHEAD)


def test_mixed_labeled_and_unlabeled_scans_are_refused_in_slam() -> None:
    est = Isam2Slam()
    _start(est)
    est.update(LidarScan(0.0, None, np.array([[0.1, 0.0, 10.0]]), SIGMA))
    with pytest.raises(ValueError, match="labeled and unlabeled scans in one SLAM run"):
        est.update(LidarScan(0.1, np.array([0]), np.array([[0.1, 0.0, 10.0]]), SIGMA))


@pytest.mark.parametrize(
    ("params", "fragment"),
    [
        ({"association": "x"}, "estimator.params.association: got 'x'; allowed: one of"),
        ({"gate_probability": 0.0}, "estimator.params.gate_probability: got 0.0; allowed"),
        ({"confirm_hits": 0}, "estimator.params.confirm_hits: got 0; allowed"),
        ({"confirm_hits": 4, "confirm_window": 3}, "estimator.params.confirm_window: got 3"),
        ({"new_landmark_probability": 0.5}, "estimator.params.new_landmark_probability"),
        ({"association": 1}, "estimator.params.association: got 1; allowed: one of"),
    ],
)
def test_bad_association_settings_name_the_key(params: dict[str, Any], fragment: str) -> None:
    with pytest.raises(ValueError) as err:
        Isam2Settings.from_dict(params)
    assert fragment in str(err.value)
