"""The cells of ``quadslam study estimators`` (:mod:`agents.studies.estimators`): its
scenarios, its estimators and the settings each gets (kept apart from the runner so that the
CLI can list them without importing the simulation)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

ZERO_Q = [0.0] * 9
SCENARIOS: dict[str, dict[str, Any]] = {
    "paper_ekf_figure8_known": {"imu": {"process_noise": ZERO_Q}},
    "paper_ekf_figure8": {"imu": {"process_noise": ZERO_Q}},
    "ekf_figure8_biased_imu": {"imu": {"process_noise": ZERO_Q, "estimate_imu_bias": True}},
    # 30 s as the FastSLAM reproduction and its bound (docs/reproducing.md).
    "paper_fastslam_helix": {
        "imu": {"process_noise": ZERO_Q, "estimate_imu_bias": True},
        "duration_s": 30.0,
    },
}
"""The scenarios and, per scenario, the IMU model of the IMU-input estimators (EKF-SLAM and
iSAM2 share these keys): the figure-8 scenarios' own (no extra process noise, biases
estimated when the IMU is biased), the same on the helix, whose scenario is FastSLAM's."""
IMU_INPUT = ("ekf_slam", "isam2")


@dataclass(frozen=True)
class Row:
    """An estimator of the table: its key, label, name and ``estimator.params``."""

    key: str
    label: str
    name: str
    params: dict[str, Any] = field(default_factory=dict)


# The smoother gets EKF-SLAM's specific-force model too (the thrust axis only, seed 001 eq. 25;
# exact for these drag-free vehicles), which the bound also assumes.
_THRUST = {"thrust_axis_accel": True}
ROWS = (
    Row("ekf_slam", "EKF-SLAM", "ekf_slam"),
    Row("fastslam", "FastSLAM", "fastslam"),
    Row("isam2_lag", "iSAM2 fixed lag", "isam2", _THRUST),
    Row("isam2_full", "iSAM2 full", "isam2", {"window_s": None, **_THRUST}),
)


def cell_overrides(scenario: str, row: Row) -> dict[str, Any]:
    """The scenario overrides that put ``row``'s estimator into ``scenario``."""
    params = {**SCENARIOS[scenario]["imu"], **row.params} if row.name in IMU_INPUT else row.params
    return {
        "estimator": {"name": row.name, "params": dict(params)},
        "episode": {"report_step_time": True},
    }
