"""The estimator run-time: how the core feeds an estimator and reads it back (docs/design.md
§3, §4; docs/timing.md). The IMU samples of a control period, an estimator replayed at a slower
IMU's instants or behind a late LiDAR (and the period log both replay), the core's side of data
association, and the integrity monitor's terms in ``info``."""
