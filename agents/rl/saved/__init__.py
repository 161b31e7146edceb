"""What a training run leaves on disk and how it is read back without running code: the run
folder and its names (:mod:`~agents.rl.saved.run_folder`), the manifest of the setup it was
trained on (:mod:`~agents.rl.saved.manifest`), the weights and statistics as arrays
(:mod:`~agents.rl.saved.safe_files`) and the checkpoints (:mod:`~agents.rl.saved.checkpoints`)."""
