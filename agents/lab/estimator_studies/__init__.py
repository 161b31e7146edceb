"""The studies and analyses that judge estimators: the Cramér–Rao bounds, Monte-Carlo
consistency, the estimators against the bound, unknown association, integrity, cooperative
fusion, degradation out of view, soak, the IMU's instants and the particles' NEES
(``quadslam study NAME``)."""
