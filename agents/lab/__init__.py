"""The lab: what reproduces the package's figures rather than what a user imports to act. The
``quadslam`` command line (:mod:`agents.lab.cli`), the studies of controllers
(:mod:`agents.lab.control_studies`) and of estimators (:mod:`agents.lab.estimator_studies`), all
run as ``quadslam study NAME``, the benchmark (:mod:`agents.lab.bench`) and the sweeps
(:mod:`agents.lab.sweep`). It builds on :mod:`agents.control`, :mod:`agents.rl`,
:mod:`agents.evaluation` and :mod:`agents.io`, which never import it (docs/design.md §1)."""
