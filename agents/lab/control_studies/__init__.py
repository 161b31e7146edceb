"""The studies that judge controllers, baselines and learned rows alike, each beside its
Oracle row (``quadslam study cost-of-estimation | robustness | active-perception |
integrity-task``), and what their learned rows share: the trainings and the flights on
held-out seeds."""
