"""quadslam: a Gymnasium environment for estimation-aware quadcopter control.

Registered ids (plain-data kwargs only):

- ``QuadSLAM-v0``: fully configurable; default scenario ``paper_ekf_figure8`` (EKF-SLAM).
- ``QuadSLAM-EKF-v0``: EKF-SLAM in the loop.
- ``QuadSLAM-FastSLAM-v0``: dynamics-based FastSLAM, scenario ``paper_fastslam_helix``.
- ``QuadSLAM-Oracle-v0``: the estimator returns the truth (for ablations).
- ``QuadSLAM-ActivePerception-v0``: scenario ``active_perception`` (EKF-SLAM): few landmarks, a
  free heading set by a fifth action component, the nearest mapped landmarks in the
  observation; where the vehicle looks decides what the filter knows.

Each id has a native vector env (``gymnasium.make_vec(id, num_envs=B)``): B lanes of the
batched simulation core in one process.

Several vehicles in one world: ``quadslam_env.team.parallel_env(n_vehicles=N)``, a PettingZoo
``ParallelEnv`` (the ``[team]`` extra; not imported here).
"""

from gymnasium.envs.registration import register

from quadslam_env._version import __version__
from quadslam_env.config import ConfigError, ScenarioConfig, load_scenario
from quadslam_env.models.params import VehicleParams, vehicle_preset

ENV_IDS = (
    "QuadSLAM-v0",
    "QuadSLAM-EKF-v0",
    "QuadSLAM-FastSLAM-v0",
    "QuadSLAM-Oracle-v0",
    "QuadSLAM-ActivePerception-v0",
)

_ENTRY = "quadslam_env.env:QuadSLAMEnv"
_VECTOR_ENTRY = "quadslam_env.vector_env:QuadSLAMVectorEnv"
_KWARGS: dict[str, dict[str, str]] = {
    "QuadSLAM-v0": {},
    "QuadSLAM-EKF-v0": {"estimator_name": "ekf_slam"},
    "QuadSLAM-FastSLAM-v0": {"scenario": "paper_fastslam_helix", "estimator_name": "fastslam"},
    "QuadSLAM-Oracle-v0": {"estimator_name": "oracle"},
    "QuadSLAM-ActivePerception-v0": {"scenario": "active_perception", "estimator_name": "ekf_slam"},
}
for _id, _kwargs in _KWARGS.items():
    register(id=_id, entry_point=_ENTRY, vector_entry_point=_VECTOR_ENTRY, kwargs=_kwargs)

__all__ = [
    "ENV_IDS",
    "ConfigError",
    "ScenarioConfig",
    "VehicleParams",
    "__version__",
    "load_scenario",
    "vehicle_preset",
]
