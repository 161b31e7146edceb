"""The cells of ``quadslam study estimators`` (:mod:`agents.lab.estimator_studies.estimators`): its
scenarios, its estimators and the settings each gets (kept apart from the runner so that the
CLI can list them without importing the simulation)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

ZERO_Q = [0.0] * 9
# The known-map scenario starts the estimate at the true pose (``sample_initial_error: false``)
# under Table 6's P0, a belief: the bound's prior is then zero
# (agents/lab/estimator_studies/bound.py), and an estimator told P0 weighs its first scans as if
# its start were 0.1 m off. This P0 tells it the start it has (pose block zero; the body rates'
# 1e-6 rad²/s² as in the scenario file).
TOLD_START_P0 = [0.0] * 9 + [1.0e-6] * 3
SCENARIOS: dict[str, dict[str, Any]] = {
    "paper_ekf_figure8_known": {"imu": {"process_noise": ZERO_Q}},
    "paper_ekf_figure8_known@start": {
        "scenario": "paper_ekf_figure8_known",
        "imu": {"process_noise": ZERO_Q},
        "estimator": {"initial_cov_diag": TOLD_START_P0},
    },
    "paper_ekf_figure8": {"imu": {"process_noise": ZERO_Q}},
    "ekf_figure8_biased_imu": {"imu": {"process_noise": ZERO_Q, "estimate_imu_bias": True}},
    # 30 s as the FastSLAM reproduction and its bound (docs/reproducing.md).
    "paper_fastslam_helix": {
        "imu": {"process_noise": ZERO_Q, "estimate_imu_bias": True},
        "duration_s": 30.0,
    },
}
"""The cells' scenarios and, per cell, the IMU model of the IMU-input estimators (EKF-SLAM and
iSAM2 share these keys): the figure-8 scenarios' own (no extra process noise, biases
estimated when the IMU is biased), the same on the helix, whose scenario is FastSLAM's. A cell
whose key is not a scenario names its ``scenario`` and the ``estimator`` overrides (P0) that
every row gets there: ``paper_ekf_figure8_known@start`` is the known map with each estimator
told its exact start, the prior the bound has."""
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


def cell_scenario(cell: str) -> str:
    """The scenario file a cell (a key of :data:`SCENARIOS`) flies."""
    return str(SCENARIOS[cell].get("scenario", cell))


def cell_overrides(cell: str, row: Row) -> dict[str, Any]:
    """The scenario overrides that put ``row``'s estimator into ``cell``."""
    spec = SCENARIOS[cell]
    params = {**spec["imu"], **row.params} if row.name in IMU_INPUT else row.params
    return {
        "estimator": {**spec.get("estimator", {}), "name": row.name, "params": dict(params)},
        "episode": {"report_step_time": True},
    }
