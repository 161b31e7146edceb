"""The episode's interface to an agent: actions, the observation built from the estimate,
reward, termination, where an episode starts, and the checks of ``reset``'s arguments
(docs/design.md §4)."""
