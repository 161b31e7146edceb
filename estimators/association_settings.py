"""The data-association settings the SLAM estimators share (``estimator.params``).

EKF-SLAM and the iSAM2 smoother gate each (return, landmark) pair on its χ²₃ Mahalanobis
distance (seed 004 §5.1), pair the returns by nearest neighbour or JCBB
(:mod:`estimators.association`) and keep clutter out of the map with tentative landmarks under
the M-of-N rule (:mod:`estimators.tentative`); the FastSLAM filters gate and confirm the same
way per particle. Their settings classes inherit these fields, with the same defaults and the
same checks, from :class:`GatedFields` (the gate and the M-of-N rule) or
:class:`AssociationFields` (plus the pairing method and the new-landmark gate).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

from estimators.association import chi2_threshold
from quadslam_env.schema import ConfigError, Section, spec

ASSOCIATION_METHODS = ("nn", "jcbb")
"""``estimator.params.association`` choices: nearest neighbour, joint compatibility B&B."""

MAX_CONFIRM = 1000
"""Largest accepted ``confirm_hits`` / ``confirm_window``."""

NEW_LANDMARK_PROBABILITY = 0.9999
"""Default p of the new-landmark gate (or ``gate_probability`` if larger)."""


@dataclass(frozen=True)
class GatedFields(Section):
    """The χ²₃ gate and the M-of-N rule of tentative landmarks (a base of settings classes)."""

    SECTION: ClassVar[str] = "estimator.params"
    gate_probability: float = spec(
        0.99,
        lo=0.0,
        lo_open=True,
        hi=1.0,
        doc="p of the χ²₃ gate on a (return, landmark) pair's NIS (0.99: 11.345); 1: no gate",
    )
    confirm_hits: int = spec(
        3,
        kind="int",
        lo=1,
        hi=MAX_CONFIRM,
        doc="M of the M-of-N rule: sightings a tentative landmark needs to be mapped",
    )
    confirm_window: int = spec(
        5,
        kind="int",
        lo=1,
        hi=MAX_CONFIRM,
        doc="N of the M-of-N rule, scans (at least confirm_hits)",
    )

    @property
    def gate(self) -> float:
        """The χ²₃ quantile of :attr:`gate_probability` on a pair's NIS (inf when it is 1)."""
        return chi2_threshold(3, self.gate_probability)

    def validate(self) -> None:
        """The window must hold the hits.

        Raises:
            ConfigError: ``confirm_window`` < ``confirm_hits``.
        """
        super().validate()
        if self.confirm_window < self.confirm_hits:
            raise ConfigError(
                f"{self.SECTION}.confirm_window: got {self.confirm_window!r}; allowed: an "
                f"integer in [confirm_hits = {self.confirm_hits}, {MAX_CONFIRM}]"
            )


@dataclass(frozen=True)
class AssociationFields(GatedFields):
    """The gate, the M-of-N rule, the pairing method and the new-landmark gate (a base of the
    EKF-SLAM and iSAM2 settings)."""

    association: str = spec(
        "jcbb",
        kind="str",
        choices=ASSOCIATION_METHODS,
        doc="nn: nearest neighbour; jcbb: joint compatibility branch and bound, both gated at "
        "gate_probability",
    )
    new_landmark_probability: float = spec(
        None,
        lo=0.0,
        lo_open=True,
        hi=1.0,
        optional=True,
        doc="a return starts a tentative landmark only outside this χ²₃ gate of every "
        "landmark (one between the two gates is dropped); at least gate_probability and < 1; "
        f"null: {NEW_LANDMARK_PROBABILITY} or gate_probability if larger",
    )

    def __post_init__(self) -> None:
        if self.new_landmark_probability is None:
            floor = self.gate_probability if self.gate_probability < 1.0 else 0.0
            object.__setattr__(
                self, "new_landmark_probability", max(NEW_LANDMARK_PROBABILITY, floor)
            )

    def validate(self) -> None:
        """The new-landmark gate lies outside the association gate.

        Raises:
            ConfigError: ``new_landmark_probability`` outside [gate_probability, 1).
        """
        super().validate()
        floor = self.gate_probability if self.gate_probability < 1.0 else 0.0
        if not floor <= self.new_landmark_probability < 1.0:
            raise ConfigError(
                f"{self.SECTION}.new_landmark_probability: got "
                f"{self.new_landmark_probability!r}; allowed: max(gate_probability = "
                f"{self.gate_probability} if < 1, 0) <= p < 1, p > 0"
            )
