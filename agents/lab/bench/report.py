"""The JSON of ``quadslam bench --json`` as Markdown tables, for the documentation.

docs/performance.md asks for them with generated-section markers (``tools/mkdocs_hooks.py``
through :mod:`agents.lab.cli.reference`), so the published figures are the measured ones.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from agents.lab.bench.runner import best_batches


def figure(value: float) -> str:
    """``value`` to 4 significant digits with thousands separators (80,780; 236,300; 0.9055)."""
    if value == 0:
        return "0"
    rounded = float(f"{value:.4g}")
    return f"{rounded:,.0f}" if abs(rounded) >= 1000 else f"{rounded:.4g}"


def _spread(entry: dict[str, Any]) -> str:
    """``median (min–max)`` of an entry."""
    return f"{figure(entry['median'])} ({figure(entry['min'])}–{figure(entry['max'])})"


def vector_markdown(doc: dict[str, Any]) -> str:
    """Median env-steps/s of each ``vector`` series against the lanes B, its best B in bold;
    '' without a ``vector`` section."""
    series: dict[str, dict[int, float]] = {}
    for e in doc["results"]:
        if e["group"] == "vector" and e["params"].get("workers", 1) == 1:
            series.setdefault(e["name"], {})[e["params"]["num_envs"]] = e["median"]
    if not series:
        return ""
    best = best_batches(doc["results"])
    batches = sorted({b for row in series.values() for b in row})
    lines = [
        "| series | " + " | ".join(f"B = {b}" for b in batches) + " |",
        "|---|" + "---|" * len(batches),
    ]
    for name, row in series.items():
        cells = []
        for b in batches:
            text = figure(row[b]) if b in row else "–"
            cells.append(f"**{text}**" if best[name]["num_envs"] == b else text)
        label = name.removeprefix("env_steps_per_s/")
        lines.append(f"| `{label}` | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def scalar_markdown(doc: dict[str, Any]) -> str:
    """Steps/s of the scalar env per estimator, DF-LQR and zero action, median (min–max),
    and DF-LQR's real-time factor; '' without an ``env`` section."""
    rows: dict[str, dict[str, dict[str, Any]]] = {}
    for e in doc["results"]:
        if e["group"] == "env":
            what, label, policy = e["name"].split("/")
            rows.setdefault(label, {})[f"{what}/{policy}"] = e
    if not rows:
        return ""
    lines = [
        "| estimator | DF-LQR, steps/s | real-time factor | zero action, steps/s |",
        "|---|---|---|---|",
    ]
    for label, got in rows.items():
        rtf = figure(got["real_time_factor/dflqr"]["median"])
        lines.append(
            f"| `{label}` | {_spread(got['steps_per_s/dflqr'])} | {rtf}× | "
            f"{_spread(got['steps_per_s/zero'])} |"
        )
    return "\n".join(lines)


def physics_markdown(doc: dict[str, Any]) -> str:
    """The ``physics`` section's two speeds and their ratio, median (min–max); '' without it."""
    lines = []
    for e in doc["results"]:
        if e["group"] == "physics":
            name = e["name"].removeprefix("env_steps_per_s/")
            lines.append(f"| `{name}` | {_spread(e)} | {e['unit']} | {e['n']} |")
    if not lines:
        return ""
    head = ["| measurement | median (min–max) | unit | samples |", "|---|---|---|---|"]
    return "\n".join([*head, *lines])


def bench_markdown(path: Path) -> str:
    """Every table of the bench JSON at ``path``, after a line naming its machine and plan."""
    doc = json.loads(path.read_text())
    machine = doc["machine"]
    head = (
        f"*`{path.name}`: {machine['cpu']} ({machine['cores']} cores), plan `{doc['plan']}`, "
        f"sections {', '.join(doc['sections'])}, {doc['wall_time_s'] / 60:.1f} min; medians "
        f"of the repeats.*"
    )
    tables = (vector_markdown(doc), scalar_markdown(doc), physics_markdown(doc))
    return "\n\n".join([head, *(t for t in tables if t)])
