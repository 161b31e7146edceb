"""quadslam: a Gymnasium environment for estimation-aware quadcopter control.

Registered ids (plain-data kwargs only):

- ``QuadSLAM-v0``: fully configurable; default scenario ``paper_ekf_figure8`` (EKF-SLAM).
- ``QuadSLAM-EKF-v0``: EKF-SLAM in the loop.
- ``QuadSLAM-FastSLAM-v0``: dynamics-based FastSLAM, scenario ``paper_fastslam_helix``.
- ``QuadSLAM-Oracle-v0``: the estimator returns the truth (for ablations).
"""

from gymnasium.envs.registration import register

from quadslam_env.config import ConfigError, ScenarioConfig, load_scenario
from quadslam_env.models.dynamics import VehicleParams, vehicle_preset

ENV_IDS = ("QuadSLAM-v0", "QuadSLAM-EKF-v0", "QuadSLAM-FastSLAM-v0", "QuadSLAM-Oracle-v0")

_ENTRY = "quadslam_env.env:QuadSLAMEnv"
register(id="QuadSLAM-v0", entry_point=_ENTRY)
register(id="QuadSLAM-EKF-v0", entry_point=_ENTRY, kwargs={"estimator_name": "ekf_slam"})
register(
    id="QuadSLAM-FastSLAM-v0",
    entry_point=_ENTRY,
    kwargs={"scenario": "paper_fastslam_helix", "estimator_name": "fastslam"},
)
register(id="QuadSLAM-Oracle-v0", entry_point=_ENTRY, kwargs={"estimator_name": "oracle"})

__all__ = [
    "ENV_IDS",
    "ConfigError",
    "ScenarioConfig",
    "VehicleParams",
    "load_scenario",
    "vehicle_preset",
]
