"""Agents (layer 5), one subpackage per concept, each importing only the ones listed below it.

- :mod:`agents.lab`: the lab, what reproduces the figures: the ``quadslam`` command and the
  docs' generated reference, the studies of controllers and of estimators, the benchmark and
  the Ray sweeps;
- :mod:`agents.rl`: stable-baselines3 training and loading, the residual wrappers, the SB3
  vector-env adapter;
- :mod:`agents.evaluation`: seeded episodes of a policy, their summaries, figures and videos;
- :mod:`agents.control`: the baselines (DF-LQR, LQI, SE(3)) and the look-at heuristic;
- :mod:`agents.io`: output files written atomically, ``--set`` overrides, process memory.

Importing a package imports none of its modules.
"""
