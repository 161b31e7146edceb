"""Where scenario files live and how they are read (YAML, merging, descriptions).

The shipped scenarios and agent hyperparameters are package data under
``quadslam_env/configs`` (read through :mod:`importlib.resources`, so a wheel install finds them
from any working directory); ``QUADSLAM_CONFIG_DIR`` points to another folder with the same
layout (``scenarios/*.yaml``, ``agents/*.yaml``).

A scenario file may carry a top-level ``description:``, one line that ``quadslam scenarios``
lists next to its name.
"""

from __future__ import annotations

import copy
import os
import re
from importlib import resources
from pathlib import Path
from typing import Any

import yaml

from quadslam_env.config_schema import ConfigError

#: Longest accepted scenario ``description`` (one line of a terminal table).
MAX_DESCRIPTION_CHARS = 160


def config_dir() -> Path:
    """Package data ``quadslam_env/configs`` (``QUADSLAM_CONFIG_DIR`` overrides)."""
    env = os.environ.get("QUADSLAM_CONFIG_DIR")
    if env:
        return Path(env)
    # Package data (pyproject's package-data), so a wheel install finds it from any folder.
    return Path(str(resources.files("quadslam_env") / "configs"))


def available_scenarios() -> list[str]:
    """Names of the scenario files shipped in ``configs/scenarios``."""
    return sorted(p.stem for p in (config_dir() / "scenarios").glob("*.yaml"))


def deep_merge(base: dict[str, Any], override: dict[str, Any]) -> dict[str, Any]:
    """Recursively merge ``override`` into a copy of ``base`` (mappings merge, others replace)."""
    out = copy.deepcopy(base)
    for key, value in override.items():
        if isinstance(value, dict) and isinstance(out.get(key), dict):
            out[key] = deep_merge(out[key], value)
        else:
            out[key] = copy.deepcopy(value)
    return out


class _YamlLoader(yaml.SafeLoader):
    """PyYAML's safe loader that also reads ``1e-4`` as a float.

    PyYAML follows YAML 1.1, where a float needs a dot (``1.0e-4``) and ``1e-4`` is the string
    ``"1e-4"``; config values would then fail validation with a confusing message.
    """


_YamlLoader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(r"^[-+]?(?:[0-9][0-9_]*)(?:\.[0-9_]*)?[eE][-+]?[0-9]+$"),
    list("-+0123456789"),
)


def parse_yaml(text: str) -> Any:
    """``yaml.safe_load`` that also reads exponent floats without a dot (``1e-4``)."""
    return yaml.load(text, Loader=_YamlLoader)  # a SafeLoader subclass: no arbitrary objects


def load_yaml(path: Path) -> dict[str, Any]:
    """Read a YAML mapping, with errors that name the file."""
    try:
        text = path.read_text()
    except OSError as exc:
        raise ConfigError(f"scenario file {str(path)!r}: cannot be read ({exc.strerror})") from exc
    try:
        data = parse_yaml(text)
    except yaml.YAMLError as exc:
        raise ConfigError(f"scenario file {str(path)!r}: malformed YAML ({exc})") from exc
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise ConfigError(
            f"scenario file {str(path)!r}: got {type(data).__name__}; "
            "allowed: a YAML mapping of sections"
        )
    return data


def check_description(value: Any, where: str = "description") -> str:
    """Validate a scenario's ``description``: one non-empty line of at most 160 characters.

    Raises:
        ConfigError: The message names ``where``, the value and what is allowed.
    """
    ok = (
        isinstance(value, str)
        and value.strip() != ""
        and "\n" not in value.strip()
        and len(value) <= MAX_DESCRIPTION_CHARS
    )
    if not ok:
        raise ConfigError(
            f"{where}: got {value!r}; allowed: one line of text "
            f"(1-{MAX_DESCRIPTION_CHARS} characters)"
        )
    return str(value).strip()


def scenario_descriptions() -> dict[str, str]:
    """Each shipped scenario's name and its one-line ``description`` (empty if it has none).

    Raises:
        ConfigError: A scenario file is malformed or its description is not one line.
    """
    out = {}
    for name in available_scenarios():
        path = config_dir() / "scenarios" / f"{name}.yaml"
        text = load_yaml(path).get("description")
        out[name] = "" if text is None else check_description(text, f"{path.name}: description")
    return out
