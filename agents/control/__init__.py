"""Controllers: the DF-LQR baseline and the look-at heuristic (on the env and estimators only)."""
