"""Several vehicles in one world: the team env, a PettingZoo ``ParallelEnv`` (docs/team.md).

``parallel_env(n_vehicles=N, scenario=..., team={...}, **overrides)`` builds N vehicles as the
N lanes of one simulation core sharing the landmark field; needs the ``[team]`` extra
(pettingzoo).
"""

from quadslam_env.team.env import TeamParallelEnv, parallel_env

__all__ = ["TeamParallelEnv", "parallel_env"]
