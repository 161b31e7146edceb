"""The ``quick`` plan measures what the ``full`` plan does, on fewer and smaller samples: the same
sections, the same JSON document, sizes taken from the full plan's; and the end of the output
says whether each target and the plan's wall-time budget were met. Nothing here measures
anything (the sections are stubs) and nothing is timed.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import pytest

from agents.lab.bench import render
from agents.lab.bench import runner as bench
from agents.lab.bench.plan import FULL, PLANS, QUICK, Plan, Results


@pytest.fixture
def stub_sections(monkeypatch: pytest.MonkeyPatch) -> None:
    """Every section replaced by a stub that adds one entry named after it."""

    def stub(name: str) -> Callable[[Results, Plan], None]:
        def section(results: Results, plan: Plan) -> None:
            results.add(f"stub/{name}", "stub", [1.0], "s", plan=plan.name)

        return section

    monkeypatch.setattr(bench, "sections", lambda: {n: stub(n) for n in bench.SECTION_NAMES})


def test_quick_and_full_documents_have_the_same_sections_and_keys(stub_sections: None) -> None:
    quick = bench.run_bench(True, progress=False)
    full = bench.run_bench(False, progress=False)
    assert (quick["plan"], full["plan"]) == ("quick", "full")
    assert quick["sections"] == full["sections"]
    assert set(quick["sections"]) | set(quick["skipped"]) == set(bench.SECTION_NAMES)
    assert set(quick) == set(full)
    assert {e["group"] for e in quick["results"]} == {e["group"] for e in full["results"]}
    for doc in (quick, full):
        assert list(doc["section_wall_s"]) == doc["sections"]
        assert 0.0 <= sum(doc["section_wall_s"].values()) <= doc["wall_time_s"]


def test_wall_time_counts_from_the_given_start(stub_sections: None) -> None:
    doc = bench.run_bench(True, only=["ekf"], progress=False, started=-1e6)
    assert doc["wall_time_s"] > 1e6  # from the caller's start, not from run_bench's


@pytest.mark.parametrize("field", [f.name for f in dataclasses.fields(Plan)])
def test_quick_sizes_are_some_of_the_full_sizes(field: str) -> None:
    """Every size loop of every section runs at least once in the quick plan, on sizes the
    full plan also measures, and no count exceeds the full plan's."""
    quick, full = getattr(QUICK, field), getattr(FULL, field)
    if isinstance(full, tuple):
        assert quick and set(quick) <= set(full)
    elif isinstance(full, int) and not isinstance(full, bool):
        assert 1 <= quick <= full


def test_every_plan_has_render_sizes_and_only_quick_a_budget() -> None:
    assert set(render.SIZES) == set(PLANS)
    for name in PLANS:
        frames, warmup_s, episode_s, repeats = render.SIZES[name]
        assert frames >= 1 and warmup_s > 0 and episode_s > 0 and repeats >= 1
    assert QUICK.wall_budget_s == 60.0 and FULL.wall_budget_s is None


def test_targets_are_reported_met_or_not() -> None:
    results = Results()
    results.add("compile", "first_use/empty_cache", [25.0], "s", target_s=20.0)
    results.add("compile", "first_use/warm_cache", [1.5], "s", target_s=2.0)
    results.add("env", "steps_per_s", [100.0], "steps/s")
    lines = bench.format_targets(results.entries).splitlines()
    assert len(lines) == 2
    assert "first_use/empty_cache: 25 s" in lines[0] and lines[0].endswith(": NOT met")
    assert "<= 2 s" in lines[1] and lines[1].endswith(": met")


def test_wall_times_against_the_budget() -> None:
    doc = {"wall_time_s": 61.0, "section_wall_s": {"ekf": 1.0, "compile": 30.0}}
    text = bench.format_wall_times(doc, ("quick", 60.0))
    assert "ekf 1.0 s, compile 30.0 s" in text
    assert text.endswith(
        "wall time 61.0 s from the command's start (OVER the quick plan's budget of 60 s; "
        "the longest section: compile 30.0 s)"
    )
    assert "within" in bench.format_wall_times({**doc, "wall_time_s": 59.0}, ("quick", 60.0))
    assert "budget" not in bench.format_wall_times(doc)
