"""Reference tables generated from the code, for the documentation site.

The documentation's settings and CLI pages are built from these functions at build time (a
MkDocs hook, ``tools/mkdocs_hooks.py``), so they cannot drift from what the code validates:

- :func:`scenario_settings_markdown`: every scenario setting with its default, accepted values
  and meaning, read from the typed field specs of :mod:`quadslam_env.config`, plus the presets;
- :func:`estimator_params_markdown`: the ``estimator.params`` keys of the built-in estimators,
  read from the same typed field specs of their settings classes;
- :func:`cli_markdown`: the ``--help`` of every ``quadslam`` command.
"""

from __future__ import annotations

import inspect
import json
import os
import re
from typing import Any

from quadslam_env.config.files import scenario_descriptions
from quadslam_env.config.scenario import SECTIONS
from quadslam_env.models.params import VEHICLE_PRESETS
from quadslam_env.schema import Section, field_rows


def _cell(value: Any) -> str:
    """A value as it is written in a YAML scenario, escaped for a Markdown table cell."""
    text = "null" if value is None else json.dumps(value, ensure_ascii=False)
    if isinstance(value, float) and value != 0 and (abs(value) < 1e-3 or abs(value) >= 1e5):
        text = f"{value:.4g}"
    return text.replace("|", "\\|")


def _escape(text: str) -> str:
    """Escape table pipes and drop Sphinx roles (``:mod:`x``` becomes ```x```)."""
    return re.sub(r":(?:mod|func|class|meth|data):", "", text).replace("|", "\\|")


def _section_table(name: str, section: type[Section]) -> list[str]:
    """A heading, the first line of the section's docstring and its settings table (key,
    default, allowed, meaning), as Markdown lines."""
    doc = inspect.getdoc(section) or ""
    out = [f"### `{name}`", "", doc.splitlines()[0] if doc else "", ""]
    out += ["| key | default | allowed | meaning |", "|---|---|---|---|"]
    for row in field_rows(section):
        out.append(
            f"| `{row.key}` | `{_cell(row.default)}` | {_escape(row.allowed)} "
            f"| {_escape(row.doc)} |"
        )
    out.append("")
    return out


def scenario_settings_markdown() -> str:
    """One Markdown table per scenario section (key, default, allowed, meaning) and the presets."""
    out = []
    for name, section in SECTIONS.items():
        out += _section_table(name, section)
        if section.PRESETS:
            out += [f"Presets of `{name}.preset` (explicit keys override them):", ""]
            keys = sorted({k for values in section.PRESETS.values() for k in values})
            out += ["| preset | " + " | ".join(f"`{k}`" for k in keys) + " |"]
            out += ["|---" * (len(keys) + 1) + "|"]
            for preset, values in section.PRESETS.items():
                cells = [f"`{_cell(values[k])}`" if k in values else "–" for k in keys]
                out.append(f"| `{preset}` | " + " | ".join(cells) + " |")
            out.append("")
    out += ["### Vehicle presets", "", "Values of `vehicle.preset` (SI units):", ""]
    out += [
        "| preset | mass [kg] | inertia diag [kg·m²] | max thrust [N] | max torque [N·m] | rotors |"
    ]
    out += ["|---|---|---|---|---|---|"]
    for name, params in VEHICLE_PRESETS.items():
        inertia = [float(f"{params.inertia[i][i]:.4g}") for i in range(3)]
        torque = [round(float(t), 4) for t in params.max_torque]
        r = params.rotors
        rotors = (
            "–"
            if r is None
            else f"{r.layout}, L {r.arm} m, k_f {r.k_f:.4g}, k_m {r.k_m:.4g}, "
            f"τ_m {r.motor_tau} s, ω {r.omega_min:g}–{r.omega_max:.0f} rad/s"
        )
        out.append(
            f"| `{name}` | {params.mass} | {inertia} | {round(float(params.max_thrust), 3)} "
            f"| {torque} | {rotors} |"
        )
    out.append("")
    return "\n".join(out)


def shipped_scenarios_markdown() -> str:
    """The shipped scenario files and their descriptions, as a Markdown table."""
    rows = ["| scenario | description |", "|---|---|"]
    rows += [f"| `{n}` | {_escape(d)} |" for n, d in scenario_descriptions().items()]
    return "\n".join(rows) + "\n"


def estimator_settings() -> dict[str, type[Section]]:
    """The settings class of each built-in estimator (what validates its ``estimator.params``)."""
    from estimators.ekf.settings import EkfSlamSettings
    from estimators.fastslam.settings import DynamicFastSlamSettings, KinematicFastSlamSettings
    from estimators.isam2.settings import Isam2Settings
    from estimators.oracle import OracleSettings

    return {
        "ekf_slam": EkfSlamSettings,
        "fastslam": DynamicFastSlamSettings,
        "fastslam_kinematic": KinematicFastSlamSettings,
        "isam2": Isam2Settings,
        "oracle": OracleSettings,
    }


def estimator_param_keys() -> dict[str, set[str]]:
    """The ``estimator.params`` keys each built-in estimator's validator accepts."""
    return {
        name: {row.key.rsplit(".", 1)[1] for row in field_rows(settings)}
        for name, settings in estimator_settings().items()
    }


def estimator_params_markdown() -> str:
    """One table of the ``estimator.params`` keys per built-in estimator (key, default,
    allowed, meaning)."""
    out = []
    for name, settings in estimator_settings().items():
        if field_rows(settings):
            out += _section_table(name, settings)
        else:
            out += [f"### `{name}`", "", "No settings (`estimator.params` must be empty).", ""]
    return "\n".join(out)


def cli_markdown() -> str:
    """``quadslam --help`` and the help of every sub-command, as code blocks."""
    from agents.lab.cli.main import build_parser

    previous = os.environ.get("COLUMNS")
    os.environ["COLUMNS"] = "100"  # argparse wraps at $COLUMNS
    try:
        parser = build_parser()
        out = ["### `quadslam`", "", "```text", parser.format_help().rstrip(), "```", ""]
        sub = next(a for a in parser._actions if a.dest == "command")
        for name, command in sub.choices.items():  # type: ignore[union-attr]
            out += [f"### `quadslam {name}`", "", "```text", command.format_help().rstrip()]
            out += ["```", ""]
    finally:
        if previous is None:
            del os.environ["COLUMNS"]
        else:
            os.environ["COLUMNS"] = previous
    return "\n".join(out)
