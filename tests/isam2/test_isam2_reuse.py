"""The iSAM2 estimator's shared work gives what the one-off queries give.

* :func:`estimators.isam2.graph.keyframe_marginals` (one joint marginal of a keyframe and its
  landmarks) against GTSAM's per-variable queries: the keyframe's ``jointMarginalCovariance``
  and each landmark's ``marginalCovariance``, on a pose seeing four landmarks through the
  project's LiDAR factor; a subset of the landmarks read off the whole joint
  (:func:`~estimators.isam2.graph.sub_joint`) against that subset's own joint query.
* :class:`estimators.isam2.transition.ImuTransition` (the linearisation point reused from one
  prediction to the next) against a fresh one at each preintegration, ``F`` against central
  differences of GTSAM's own prediction (``δ_j = F δ_i`` for the mean), and ``F``, ``Q``
  against GTSAM's linearisation of the ``CombinedImuFactor`` itself.
* The landmark covariances recovered lazily (only when a snapshot asks for them) against
  GTSAM's per-landmark ``marginalCovariance`` of the same keyframe, in the env.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from estimators.isam2.factors import landmark_error
from estimators.isam2.graph import keyframe_marginals, sub_joint
from estimators.isam2.transition import ImuTransition
from quadslam_env.models.lidar import measure_from_body

gtsam = pytest.importorskip("gtsam")

LANDMARKS = np.array([[6.0, 1.0, -1.0], [5.0, -2.0, 0.5], [7.0, 0.0, -2.5], [4.0, 3.0, 0.0]])


def test_keyframe_marginals_equal_per_variable_queries() -> None:
    x, v, b = (gtsam.symbol(c, 0) for c in "xvb")
    lms = [gtsam.symbol("l", i) for i in range(len(LANDMARKS))]
    pose = gtsam.Pose3(gtsam.Rot3.Ypr(0.2, -0.05, 0.1), np.array([0.5, -0.3, -2.0]))
    graph = gtsam.NonlinearFactorGraph()
    values = gtsam.Values()
    graph.add(gtsam.PriorFactorPose3(x, pose, gtsam.noiseModel.Isotropic.Sigma(6, 0.05)))
    graph.add(gtsam.PriorFactorVector(v, np.zeros(3), gtsam.noiseModel.Isotropic.Sigma(3, 0.1)))
    graph.add(
        gtsam.PriorFactorConstantBias(
            b, gtsam.imuBias.ConstantBias(), gtsam.noiseModel.Isotropic.Sigma(6, 0.01)
        )
    )
    values.insert(x, pose)
    values.insert(v, np.zeros(3))
    values.insert(b, gtsam.imuBias.ConstantBias())
    noise = gtsam.noiseModel.Diagonal.Sigmas(np.array([0.006, 0.005, 0.1]))
    body = (LANDMARKS - pose.translation()) @ pose.rotation().matrix()
    for key, lm, z in zip(lms, LANDMARKS, measure_from_body(body), strict=True):
        graph.add(gtsam.CustomFactor(noise, [x, key], landmark_error(z)))
        graph.add(gtsam.PriorFactorPoint3(key, lm, gtsam.noiseModel.Isotropic.Sigma(3, 1.0)))
        values.insert(key, lm)
    isam = gtsam.ISAM2()
    isam.update(graph, values)
    cov, blocks, joint = keyframe_marginals(isam, [x, v, b], lms)
    ref = np.asarray(isam.jointMarginalCovariance([x, v, b]).fullMatrix())
    np.testing.assert_allclose(cov, ref, rtol=1e-9, atol=1e-12)
    assert cov.shape == (15, 15) and len(blocks) == len(lms)
    for key, block in zip(lms, blocks, strict=True):
        np.testing.assert_allclose(block, isam.marginalCovariance(key), rtol=1e-9, atol=1e-12)
    nav_only, none, _ = keyframe_marginals(isam, [x, v, b], [])
    np.testing.assert_allclose(nav_only, ref, rtol=1e-9, atol=1e-12)
    assert none == []
    # A subset of the landmarks, in another order: its own joint marginal with the keyframe.
    subset = [len(lms) - 1, 0, 2]
    want = isam.jointMarginalCovariance([x, v, b, *(lms[j] for j in subset)]).fullMatrix()
    np.testing.assert_allclose(sub_joint(joint, 15, subset), want, rtol=1e-9, atol=1e-12)


def _pim(samples: int, bias: Any) -> Any:
    p = gtsam.PreintegrationCombinedParams(np.array([0.0, 0.0, 9.81]))
    p.setAccelerometerCovariance(np.eye(3) * 1e-4)
    p.setGyroscopeCovariance(np.eye(3) * 1e-6)
    p.setIntegrationCovariance(np.eye(3) * 1e-8)
    p.setBiasAccCovariance(np.eye(3) * 1e-6)
    p.setBiasOmegaCovariance(np.eye(3) * 1e-8)
    pim = gtsam.PreintegratedCombinedMeasurements(p, bias)
    for n in range(samples):
        accel = np.array([0.3 * np.sin(n), 0.2, -9.6])
        pim.integrateMeasurement(accel, np.array([0.1, -0.2, 0.4 + 0.01 * n]), 0.01)
    return pim


def test_reused_transition_equals_fresh_and_differences() -> None:
    pose = gtsam.Pose3(gtsam.Rot3.Ypr(0.7, 0.1, -0.2), np.array([1.0, 2.0, -3.0]))
    vel = np.array([1.5, -0.5, 0.2])
    bias = gtsam.imuBias.ConstantBias(np.array([0.01, -0.02, 0.03]), np.array([1e-3, 0, -2e-3]))
    reused = ImuTransition(gtsam, pose, vel, bias)
    for samples in (3, 7, 10):  # successive predictions from one keyframe
        pim = _pim(samples, bias)
        got = reused(pim)
        want = ImuTransition(gtsam, pose, vel, bias)(pim)
        assert got[0].equals(want[0], 1e-15)
        for a, b in zip(got[1:], want[1:], strict=True):
            np.testing.assert_array_equal(a, b)
    # F against central differences of GTSAM's prediction in the keyframe's tangent
    # (δθ, δt, δv_N); the prediction's error is read in the same chart at j.
    pose_j, vel_j, F, Q = got
    h = 1e-6
    for i in range(9):
        d = np.zeros(9)
        d[i] = h
        outs = []
        for sign in (1.0, -1.0):
            p = pose.retract(sign * d[:6])
            nav = pim.predict(gtsam.NavState(p, vel + sign * d[6:9]), bias)
            outs.append(
                np.concatenate([pose_j.localCoordinates(nav.pose()), nav.velocity() - vel_j])
            )
        np.testing.assert_allclose((outs[0] - outs[1]) / (2 * h), F[:9, i], atol=1e-6)
    np.testing.assert_allclose(Q, Q.T, atol=1e-18)
    assert np.linalg.eigvalsh(Q).min() > 0.0


def _factor_transition(pose: Any, vel: np.ndarray, bias: Any, pim: Any) -> tuple[Any, Any]:
    """``(F, Q)`` from GTSAM's whitened Jacobian ``[A_i | A_j]`` of the ``CombinedImuFactor``
    linearised at the keyframe and its prediction: ``F = −A_j⁻¹ A_i``, ``Q = A_j⁻¹ A_j⁻ᵀ``."""
    nav = pim.predict(gtsam.NavState(pose, vel), bias)
    values = gtsam.Values()
    for key, value in enumerate((pose, vel, nav.pose(), nav.velocity(), bias, bias)):
        values.insert(key, value)
    A = gtsam.CombinedImuFactor(0, 1, 2, 3, 4, 5, pim).linearize(values).jacobian()[0]
    A_i, A_j = A[:, np.r_[0:9, 18:24]], A[:, np.r_[9:18, 24:30]]
    A_j_inv = np.linalg.inv(A_j)
    return -A_j_inv @ A_i, A_j_inv @ A_j_inv.T


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_transition_is_the_imu_factors_linearisation(seed: int) -> None:
    """``F`` and ``Q`` equal what GTSAM's own linearisation of the factor gives, and so does the
    covariance :meth:`ImuTransition.propagate` maps through them."""
    rng = np.random.default_rng(seed)
    pose = gtsam.Pose3(gtsam.Rot3.Ypr(*rng.normal(0.0, 1.0, 3)), rng.normal(0.0, 3.0, 3))
    vel = rng.normal(0.0, 2.0, 3)
    bias = gtsam.imuBias.ConstantBias(rng.normal(0.0, 0.05, 3), rng.normal(0.0, 0.01, 3))
    pim = _pim(int(rng.integers(1, 12)), bias)
    _, _, F, Q = ImuTransition(gtsam, pose, vel, bias)(pim)
    F_ref, Q_ref = _factor_transition(pose, vel, bias, pim)
    np.testing.assert_allclose(F, F_ref, atol=1e-12)
    np.testing.assert_allclose(Q, Q_ref, rtol=0.0, atol=1e-12 * np.abs(Q_ref).max())
    # The per-step covariance: a keyframe marginal P mapped by the same linearisation.
    L = rng.normal(0.0, 0.1, (15, 15))
    P = L @ L.T + 1e-4 * np.eye(15)
    _, _, R_j, cov = ImuTransition(gtsam, pose, vel, bias).propagate(pim, P)
    cov_ref = (F_ref @ P @ F_ref.T + Q_ref)[:9, :9]
    np.testing.assert_allclose(cov, cov_ref, rtol=0.0, atol=1e-12 * np.abs(cov_ref).max())
    np.testing.assert_array_equal(cov, cov.T)
    pose_j = pim.predict(gtsam.NavState(pose, vel), bias).pose()
    np.testing.assert_allclose(R_j, pose_j.rotation().matrix(), atol=1e-15)


def test_rebased_transition_equals_one_built_at_the_new_keyframe() -> None:
    """A transition moved to another keyframe (:meth:`ImuTransition.rebase`, as the estimator
    does at every keyframe) keeps its ``B_j`` from the first one: the prediction and the
    Jacobians are those of a transition built there."""
    first = gtsam.imuBias.ConstantBias(np.array([0.2, -0.1, 0.05]), np.array([0.01, 0, 0.02]))
    moved = ImuTransition(gtsam, gtsam.Pose3(), np.zeros(3), first)
    pose = gtsam.Pose3(gtsam.Rot3.Ypr(-0.4, 0.2, 0.1), np.array([-2.0, 0.5, -1.0]))
    vel = np.array([0.3, 1.2, -0.4])
    bias = gtsam.imuBias.ConstantBias(np.array([-0.03, 0.01, 0.0]), np.array([0, 2e-3, 1e-3]))
    moved.rebase(pose, vel, bias)
    pim = _pim(10, bias)
    got, want = moved(pim), ImuTransition(gtsam, pose, vel, bias)(pim)
    assert got[0].equals(want[0], 1e-15)
    np.testing.assert_array_equal(got[1], want[1])
    for a, b in zip(got[2:], want[2:], strict=True):
        np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-15)


def _landmark_marginals(lane: Any) -> dict[int, np.ndarray]:
    """GTSAM's own per-landmark marginals of the lane's smoother now."""
    isam = lane._smoother.getISAM2()
    return {i: isam.marginalCovariance(gtsam.symbol("l", i)) for i in sorted(lane._lm_means)}


def test_lazy_landmark_covariances_are_the_keyframes_marginals() -> None:
    """The env's per-step snapshot leaves the landmark covariances out; asked for later, they
    are the marginals of the keyframe the snapshot belongs to (not of an earlier one), and the
    rest of the two snapshots is the same."""
    import gymnasium as gym

    import quadslam_env  # noqa: F401  (registers the env ids)
    from agents.control.dflqr import DFLQRPolicy

    env = gym.make(
        "QuadSLAM-v0",
        scenario="paper_ekf_figure8",
        estimator={"name": "isam2"},
        episode={"duration_s": 2.0},
    )
    policy = DFLQRPolicy.from_env(env)
    obs, _ = env.reset(seed=4)
    base: Any = env.unwrapped
    lane = base.estimator.lanes[0]
    for stop in (64, 97, 152):  # between keyframes, just before one and after several
        while base.steps < stop:
            obs = env.step(policy.predict(obs)[0])[0]
        state = lane.state_estimate()
        assert state.landmark_covs is None
        want = _landmark_marginals(lane)
        assert len(want) >= 4
        full = base.last_estimate
        ids, _, covs = full.mapped_landmarks()
        assert ids.tolist() == list(want)
        for i, cov in zip(ids.tolist(), covs, strict=True):
            np.testing.assert_allclose(cov, want[i], rtol=1e-9, atol=1e-15)
        for name in ("position", "vel_body", "euler", "rates", "pose_cov", "landmark_means"):
            np.testing.assert_array_equal(getattr(full, name), getattr(state, name))
        assert lane.state_estimate() is full  # the full snapshot of the step serves the batch
