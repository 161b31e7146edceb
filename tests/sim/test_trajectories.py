"""Reference trajectories: analytic derivatives vs central finite differences.

See docs/design.md §3.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from quadslam_env.config.world import TrajectoryConfig
from quadslam_env.sim.trajectories import Trajectory

CASES = {
    "figure8": {"kind": "figure8", "amplitude_x_m": 4.0, "amplitude_y_m": 2.0, "period_s": 12.0},
    "circle": {"kind": "circle", "radius_m": 1.5, "period_s": 9.0},
    "helix": {"kind": "helix", "radius_m": 1.0, "period_s": 20.0, "climb_rate_mps": 0.3},
}
CENTER = [1.0, -2.0, -3.0]
TIMES = np.linspace(0.05, 30.0, 61)
H = 1e-5


def make(kind: str, **extra) -> Trajectory:
    return Trajectory(TrajectoryConfig.from_dict({**CASES[kind], "center": CENTER, **extra}))


def unwrap_diff(a: float, b: float) -> float:
    d = a - b
    return d - 2 * math.pi * round(d / (2 * math.pi))


@pytest.mark.parametrize("kind", sorted(CASES))
@pytest.mark.parametrize("yaw_mode", ["tangent", "fixed"])
def test_derivatives_match_finite_differences(kind, yaw_mode):
    traj = make(kind, yaw_mode=yaw_mode, yaw_deg=30.0)
    for t in TIMES:
        now, ahead, behind = traj(t), traj(t + H), traj(t - H)
        np.testing.assert_allclose(now.vel, (ahead.pos - behind.pos) / (2 * H), atol=1e-7)
        np.testing.assert_allclose(now.acc, (ahead.vel - behind.vel) / (2 * H), atol=1e-7)
        yaw_rate_fd = unwrap_diff(ahead.yaw, behind.yaw) / (2 * H)
        assert now.yaw_rate == pytest.approx(yaw_rate_fd, abs=1e-6)
        assert -math.pi < now.yaw <= math.pi


@pytest.mark.parametrize("kind", sorted(CASES))
def test_tangent_yaw_points_along_horizontal_velocity(kind):
    traj = make(kind, yaw_mode="tangent")
    for t in TIMES:
        ref = traj(t)
        heading = np.array([math.cos(ref.yaw), math.sin(ref.yaw)])
        v = ref.vel[:2]
        assert heading @ v == pytest.approx(np.linalg.norm(v), rel=1e-12)


@pytest.mark.parametrize("kind", sorted(CASES))
def test_fixed_yaw(kind):
    traj = make(kind, yaw_mode="fixed", yaw_deg=-45.0)
    for t in TIMES[::10]:
        ref = traj(t)
        assert ref.yaw == pytest.approx(math.radians(-45.0))
        assert ref.yaw_rate == 0.0


def test_known_points():
    f8 = make("figure8")
    w = 2 * math.pi / 12.0
    # x = cx + A sin ωt, y = cy + B sin 2ωt: at t = T/4, x is at its maximum and y back at cy.
    np.testing.assert_allclose(f8(3.0).pos, [CENTER[0] + 4.0, CENTER[1], CENTER[2]], atol=1e-12)
    np.testing.assert_allclose(f8(0.0).vel, [4.0 * w, 2 * 2.0 * w, 0.0], atol=1e-12)
    circle = make("circle")
    np.testing.assert_allclose(circle(0.0).pos, [CENTER[0] + 1.5, CENTER[1], CENTER[2]])
    # Circle: constant speed Rω and centripetal acceleration Rω² towards the centre.
    wc = 2 * math.pi / 9.0
    for t in TIMES[::7]:
        ref = circle(t)
        assert np.linalg.norm(ref.vel) == pytest.approx(1.5 * wc)
        np.testing.assert_allclose(ref.acc, -(wc**2) * (ref.pos - CENTER), atol=1e-12)
    # Helix climbs (NED z decreases) at the climb rate; yaw rate equals ω when tangent.
    helix = make("helix")
    for t in (0.0, 5.0, 17.0):
        assert helix(t).pos[2] == pytest.approx(CENTER[2] - 0.3 * t)
        assert helix(t).yaw_rate == pytest.approx(2 * math.pi / 20.0)


def test_hover_is_constant():
    traj = Trajectory(
        TrajectoryConfig.from_dict(
            {"kind": "hover", "center": CENTER, "yaw_mode": "fixed", "yaw_deg": 20.0}
        )
    )
    for t in (0.0, 1.0, 37.5, 1000.0):
        ref = traj(t)
        np.testing.assert_array_equal(ref.pos, CENTER)
        np.testing.assert_array_equal(ref.vel, np.zeros(3))
        np.testing.assert_array_equal(ref.acc, np.zeros(3))
        assert ref.yaw == pytest.approx(math.radians(20.0))
        assert ref.yaw_rate == 0.0
