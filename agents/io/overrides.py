"""``--set section.key=value`` overrides as nested mappings: the scenario overrides of
``quadslam run`` and ``quadslam study``."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any


def parse_overrides(items: Sequence[str]) -> dict[str, Any]:
    """Turn ``["episode.duration_s=20", "imu.preset=ideal"]`` into nested override mappings.

    Values are parsed as YAML (numbers, booleans, lists); keys are ``section.key[.key...]``.
    A key given twice (or a YAML value that repeats a key) is an error, not "last one wins".
    """
    import yaml

    from quadslam_env.config.files import parse_yaml

    out: dict[str, Any] = {}
    for item in items:
        key, sep, text = item.partition("=")
        parts = key.split(".")
        if not sep or len(parts) < 2 or not all(parts):
            raise ValueError(
                f"--set: got {item!r}; allowed: section.key=value, e.g. episode.duration_s=20"
            )
        try:
            value = parse_yaml(text)
        except yaml.YAMLError as exc:
            raise ValueError(f"--set {key}: value {text!r} is not valid YAML ({exc})") from exc
        node = out
        for part in parts[:-1]:
            node = node.setdefault(part, {})
            if not isinstance(node, dict):
                raise ValueError(f"--set: {key!r} conflicts with another --set")
        if parts[-1] in node:
            raise ValueError(f"--set {key}: given twice; allowed: each key once")
        node[parts[-1]] = value
    return out
