"""The estimate's RMSE over the Cramér–Rao bound by phase of the flight (``quadslam study bound
--phases``).

Whole-flight and steady-state ratios hide where an estimator departs from the bound: on the
known-map figure-8 the whole flight's excess sits in the first seconds (the P0 the estimator is
told against the bound's prior, docs/isam2-validation.md). Per phase ``(a, b]`` (s) and block,
pooled over seeds as the bound bounds the mean-square error::

    ratio = √(mean over seeds of mean_{a < t ≤ b} e²) / √(mean over seeds of mean_{a < t ≤ b} B)

with ``e`` the error norm and ``B`` the bound's trace of the block (position m, velocity m/s,
attitude rad). A phase no seed reaches is left out.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from typing import Any, Protocol

import numpy as np

from quadslam_env.types import FloatArray


class Series(Protocol):
    """One seed's per-step record (:class:`agents.lab.estimator_studies.bound.SeedBound`)."""

    t: FloatArray  # (K,) s
    err_norm: FloatArray  # (K, 3): position m, velocity m/s, attitude rad
    bound: dict[str, FloatArray]  # the bound's trace per block, (K,) each


Block = tuple[str, str, float, str]
"""A block: name, unit suffix, factor from SI, key of its trace in ``Series.bound``."""


def phase_ratios(
    series: Sequence[Series], edges: Sequence[float], blocks: Sequence[Block]
) -> list[dict[str, Any]]:
    """Pooled RMSE and bound per phase between consecutive ``edges`` (s, increasing).

    Args:
        series: Each seed's per-step errors and bound
            (:func:`~agents.lab.estimator_studies.bound.compute_bounds`).
        edges: Phase boundaries in s; the last phase ends at the last edge.
        blocks: The error blocks, in the column order of ``err_norm``.

    Returns:
        Per phase ``{"from_s", "to_s", "seeds", "<block>": {"est", "bound", "ratio"}}``, est
        and bound in the block's unit (attitude in degrees).
    """
    out = []
    for a, b in itertools.pairwise(edges):
        spans = [(s, (s.t > a) & (s.t <= b)) for s in series]
        reached = [(s, sel) for s, sel in spans if sel.any()]
        if not reached:
            continue
        row: dict[str, Any] = {"from_s": float(a), "to_s": float(b), "seeds": len(reached)}
        for j, (name, _, scale, term) in enumerate(blocks):
            e2 = [np.mean(s.err_norm[sel, j] ** 2) for s, sel in reached]
            b2 = [np.mean(s.bound[term][sel]) for s, sel in reached]
            est, bound = math.sqrt(np.mean(e2)), math.sqrt(np.mean(b2))
            row[name] = {
                "est": scale * est,
                "bound": scale * bound,
                "ratio": est / bound if bound > 0.0 else math.nan,
            }
        out.append(row)
    return out


def format_phases(phases: list[dict[str, Any]], blocks: Sequence[Block]) -> str:
    """One line per block: the ratio of each phase."""
    head = "RMSE / bound by phase: " + "  ".join(f"{p['from_s']:g}–{p['to_s']:g} s" for p in phases)
    lines = [head]
    for name, *_ in blocks:
        cells = "  ".join(f"{p[name]['ratio']:.3f}" for p in phases)
        lines.append(f"  {name}: {cells}")
    return "\n".join(lines)
