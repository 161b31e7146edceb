"""The data-association settings that EKF-SLAM and the iSAM2 smoother share (``estimator.params``).

Both gate each (return, landmark) pair on its χ²₃ Mahalanobis distance (seed 004 §5.1), pair
the returns by nearest neighbour or JCBB (:mod:`estimators.association`) and keep clutter out of
the map with tentative landmarks under the M-of-N rule (:mod:`estimators.tentative`), so they
read the same keys, with the same defaults and the same checks, from here.
"""

from __future__ import annotations

from typing import Any

from estimators.tentative import check_confirm_rule

ASSOCIATION_METHODS = ("nn", "jcbb")
"""``estimator.params.association`` choices: nearest neighbour, joint compatibility B&B."""

ASSOCIATION_TYPES: dict[str, type | tuple[type, ...]] = {
    "gate_probability": (float, int),
    "association": str,
    "confirm_hits": int,
    "confirm_window": int,
    "new_landmark_probability": (float, int),
}
"""Accepted types of the shared keys (for :func:`estimators.settings_check.check_kwargs`)."""

ASSOCIATION_DEFAULTS: dict[str, Any] = {
    "gate_probability": 0.99,  # χ²₃ gate: NIS ≤ 11.345
    "association": "jcbb",
    "confirm_hits": 3,  # M of the M-of-N rule
    "confirm_window": 5,  # N of the M-of-N rule, scans
    "new_landmark_probability": 0.9999,  # or gate_probability if larger
}


def association_settings(params: dict[str, Any]) -> dict[str, Any]:
    """The validated association settings of ``params`` (defaults for the missing keys), as
    keyword arguments of the settings dataclasses.

    Raises:
        ValueError: Naming the key, the value and what is allowed: ``gate_probability``
            outside (0, 1], an unknown ``association``, a bad M-of-N rule, or
            ``new_landmark_probability`` outside [gate_probability, 1).
    """
    prob = float(params.get("gate_probability", ASSOCIATION_DEFAULTS["gate_probability"]))
    if not 0.0 < prob <= 1.0:
        raise ValueError(f"estimator.params.gate_probability: got {prob!r}; allowed: 0 < p <= 1")
    method = params.get("association", ASSOCIATION_DEFAULTS["association"])
    if method not in ASSOCIATION_METHODS:
        raise ValueError(
            f"estimator.params.association: got {method!r}; allowed: one of "
            f"{list(ASSOCIATION_METHODS)}"
        )
    hits, window = check_confirm_rule(
        params.get("confirm_hits", ASSOCIATION_DEFAULTS["confirm_hits"]),
        params.get("confirm_window", ASSOCIATION_DEFAULTS["confirm_window"]),
    )
    floor = prob if prob < 1.0 else 0.0  # no association gate: any p < 1
    new_prob = float(
        params.get(
            "new_landmark_probability",
            max(ASSOCIATION_DEFAULTS["new_landmark_probability"], floor),
        )
    )
    if not (floor <= new_prob < 1.0 and new_prob > 0.0):
        raise ValueError(
            f"estimator.params.new_landmark_probability: got {new_prob!r}; allowed: "
            f"max(gate_probability = {prob} if < 1, 0) <= p < 1, p > 0"
        )
    return {
        "gate_probability": prob,
        "association": method,
        "confirm_hits": hits,
        "confirm_window": window,
        "new_landmark_probability": new_prob,
    }
