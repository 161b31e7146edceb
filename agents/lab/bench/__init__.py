"""``quadslam bench``: the runner and its sections (estimators, envs, association, processes,
rendering) and its plots."""
