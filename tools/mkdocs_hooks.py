"""MkDocs hooks: fill the generated sections of the documentation pages at build time.

A page asks for a generated section with an HTML comment marker (see ``MARKERS``); the content
comes from :mod:`agents.lab.cli.reference`, i.e. from the validated config specs, the estimators'
validators and the CLI's argument parser, and from the bench JSON files of ``docs/results``
(:func:`agents.lab.bench.report.bench_markdown`), so the pages cannot go stale.
"""

from __future__ import annotations

import sys
from collections.abc import Callable
from functools import partial
from pathlib import Path
from typing import Any

# The pages document this checkout, as mkdocstrings does (`paths: ["."]`), even where another
# copy of the package is installed (an editable install of another worktree).
ROOT = str(Path(__file__).resolve().parent.parent)
if ROOT not in sys.path:
    sys.path.insert(0, ROOT)

from agents.lab.bench.report import bench_markdown  # noqa: E402  (after the path above)
from agents.lab.cli import reference  # noqa: E402

RESULTS = Path(ROOT) / "docs" / "results"
"""The measured results the pages show (this checkout's; an installed package reads none)."""

MARKERS: dict[str, Callable[[], str]] = {
    "<!-- generated: scenario-settings -->": reference.scenario_settings_markdown,
    "<!-- generated: shipped-scenarios -->": reference.shipped_scenarios_markdown,
    "<!-- generated: estimator-params -->": reference.estimator_params_markdown,
    "<!-- generated: cli -->": reference.cli_markdown,
    "<!-- generated: bench-latest -->": partial(bench_markdown, RESULTS / "bench_latest.json"),
    "<!-- generated: bench-physics -->": partial(bench_markdown, RESULTS / "bench_physics.json"),
}


def on_page_markdown(markdown: str, **kwargs: Any) -> str:
    """Replace every generated-section marker of a page by its content."""
    for marker, make in MARKERS.items():
        if marker in markdown:
            markdown = markdown.replace(marker, make())
    return markdown
