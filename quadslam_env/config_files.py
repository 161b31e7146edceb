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


class DuplicateKeyError(yaml.YAMLError):
    """A YAML mapping names the same key twice (PyYAML would silently keep the last one).

    Attributes:
        key: The repeated key.
        first_line: 1-based line of its first occurrence.
        line: 1-based line of the repetition.
    """

    def __init__(self, key: Any, first_line: int, line: int) -> None:
        self.key, self.first_line, self.line = key, first_line, line
        super().__init__(
            f"duplicate key {key!r} at line {line} (first at line {first_line}); "
            "allowed: each key once per mapping"
        )


class _YamlLoader(yaml.SafeLoader):
    """PyYAML's safe loader that also reads ``1e-4`` as a float and rejects duplicate keys.

    PyYAML follows YAML 1.1, where a float needs a dot (``1.0e-4``) and ``1e-4`` is the string
    ``"1e-4"``; config values would then fail validation with a confusing message. A mapping
    that repeats a key (a second ``episode:`` section) raises :class:`DuplicateKeyError`
    instead of silently dropping the first; keys brought in by a ``<<`` merge may be
    overridden as YAML intends.
    """

    def construct_mapping(self, node: yaml.MappingNode, deep: bool = False) -> dict[Any, Any]:
        if isinstance(node, yaml.MappingNode):
            seen: dict[Any, int] = {}
            for key_node, _ in node.value:
                if key_node.tag == "tag:yaml.org,2002:merge":
                    continue
                key = self.construct_object(key_node, deep=True)
                line = key_node.start_mark.line + 1
                try:
                    if key in seen:
                        raise DuplicateKeyError(key, seen[key], line)
                    seen[key] = line
                except TypeError:  # an unhashable key: PyYAML reports it itself
                    continue
        return super().construct_mapping(node, deep=deep)


_YamlLoader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(r"^[-+]?(?:[0-9][0-9_]*)(?:\.[0-9_]*)?[eE][-+]?[0-9]+$"),
    list("-+0123456789"),
)


def parse_yaml(text: str) -> Any:
    """``yaml.safe_load`` that also reads exponent floats without a dot (``1e-4``).

    Raises:
        yaml.YAMLError: Malformed YAML; :class:`DuplicateKeyError` for a repeated key.
    """
    return yaml.load(text, Loader=_YamlLoader)  # a SafeLoader subclass: no arbitrary objects


def read_text_file(path: Path, what: str = "scenario file") -> str:
    """A UTF-8 text file's content, with errors that name the file.

    Raises:
        ConfigError: The file cannot be read or is not UTF-8 text.
    """
    try:
        return path.read_text(encoding="utf-8")
    except OSError as exc:
        raise ConfigError(f"{what} {str(path)!r}: cannot be read ({exc.strerror})") from exc
    except UnicodeDecodeError as exc:
        raise ConfigError(
            f"{what} {str(path)!r}: not UTF-8 text (byte {exc.object[exc.start]:#04x} at "
            f"offset {exc.start}); allowed: a UTF-8 YAML file"
        ) from None


def load_yaml(path: Path) -> dict[str, Any]:
    """Read a YAML mapping, with errors that name the file.

    Raises:
        ConfigError: Unreadable, not UTF-8, malformed YAML, a repeated key, empty (no
            mapping at all; write ``{}`` for "all defaults"), or not a mapping.
    """
    text = read_text_file(path)
    try:
        data = parse_yaml(text)
    except DuplicateKeyError as exc:
        raise ConfigError(f"scenario file {str(path)!r}: {exc}") from None
    except yaml.YAMLError as exc:
        raise ConfigError(f"scenario file {str(path)!r}: malformed YAML ({exc})") from exc
    if data is None:
        raise ConfigError(
            f"scenario file {str(path)!r}: empty (no settings); allowed: a YAML mapping of "
            "sections (write {} to mean every default)"
        )
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
