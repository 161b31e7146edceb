"""Agents (layer 5): the DF-LQR baseline, wrappers, SB3 training/evaluation and the CLI."""
