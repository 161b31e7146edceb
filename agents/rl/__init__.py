"""Learning on the envs with stable-baselines3: residual wrappers, the SB3 vector-env adapter,
hyperparameters, training, run folders and loading trained policies."""
