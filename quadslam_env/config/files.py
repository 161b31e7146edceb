"""Where scenario files live and how they are read (YAML, merging, descriptions).

The shipped scenarios, agent hyperparameters and sweep specs live in the repository's top-level
``configs/`` folder, installed as the package ``quadslam_env.configs`` (pyproject's
``package-dir``; read through :mod:`importlib.resources`, so a wheel or an editable install
finds them from any working directory); ``QUADSLAM_CONFIG_DIR`` points to another folder with
the same layout (``scenarios/*.yaml``, ``agents/*.yaml``, ``sweeps/*.yaml``).

A scenario file may carry a top-level ``description:``, one line that ``quadslam scenarios``
lists next to its name.

Inputs are bounded: a configuration file is at most :data:`MAX_CONFIG_BYTES` (checked from
its size before reading, and never more than that is read from a pipe), and a YAML document at
most :data:`MAX_YAML_NODES` nodes once its aliases are expanded and :data:`MAX_YAML_DEPTH`
levels deep, so an alias bomb ("billion laughs") or a deeply nested file is a one-line error,
not a ``MemoryError`` or a ``RecursionError`` somewhere later.
"""

from __future__ import annotations

import copy
import os
import re
import stat
from importlib import resources
from pathlib import Path
from typing import Any

import yaml

from quadslam_env.schema import ConfigError

#: Longest accepted scenario ``description`` (one line of a terminal table).
MAX_DESCRIPTION_CHARS = 160
#: Largest configuration file read (scenario, sweep spec, run config): 1 MiB.
MAX_CONFIG_BYTES = 1 << 20
#: Most YAML nodes of one document with every alias expanded (a shipped file has < 400).
MAX_YAML_NODES = 100_000
#: Deepest nesting of YAML collections (a configuration needs a handful of levels).
MAX_YAML_DEPTH = 100


def config_dir() -> Path:
    """The folder of the shipped configuration files (``QUADSLAM_CONFIG_DIR`` overrides).

    The package ``quadslam_env.configs`` (the repository's ``configs/``): from a wheel,
    ``site-packages/quadslam_env/configs``; from a source checkout, its ``configs/``.
    """
    env = os.environ.get("QUADSLAM_CONFIG_DIR")
    if env:
        return Path(env)
    # A checkout imported through PYTHONPATH has no installed `quadslam_env.configs` (or that
    # of another checkout's editable install): its own configs/ beside the package comes first.
    # An installed package has no pyproject.toml beside it.
    root = Path(__file__).resolve().parent.parent
    if (root / "pyproject.toml").is_file() and (root / "configs" / "__init__.py").is_file():
        return root / "configs"
    return Path(str(resources.files("quadslam_env.configs")))


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


class YamlLimitError(yaml.YAMLError):
    """A YAML document beyond the size or depth any configuration needs (an alias bomb)."""


def _children(node: yaml.Node) -> list[yaml.Node]:
    if isinstance(node, yaml.SequenceNode):
        return list(node.value)
    if isinstance(node, yaml.MappingNode):
        return [part for pair in node.value for part in pair]
    return []


def check_node_graph(root: yaml.Node) -> None:
    """Refuse a composed document whose expanded size or depth is beyond the limits.

    Aliases share nodes, so the graph is small even when the document it stands for is
    astronomically large; sizes are summed with every alias counted in full (each node's size
    computed once), iteratively, so neither the count nor Python's stack can blow up.

    Raises:
        YamlLimitError: More than :data:`MAX_YAML_NODES` expanded nodes, nesting deeper than
            :data:`MAX_YAML_DEPTH`, or an alias inside its own anchor (a recursive document).
    """
    sizes: dict[int, int] = {}
    on_path: set[int] = set()
    stack: list[tuple[yaml.Node, bool]] = [(root, False)]
    while stack:
        node, finished = stack.pop()
        key = id(node)
        if finished:
            on_path.discard(key)
            size = 1 + sum(sizes[id(child)] for child in _children(node))
            if size > MAX_YAML_NODES:
                raise YamlLimitError(
                    f"more than {MAX_YAML_NODES:,} values once its aliases are expanded "
                    f"(line {node.start_mark.line + 1}); allowed: a configuration of at most "
                    f"{MAX_YAML_NODES:,} values (an alias bomb is refused)"
                )
            sizes[key] = size
            continue
        if key in sizes:
            continue
        if key in on_path:
            raise YamlLimitError(
                f"an alias refers to its own anchor (line {node.start_mark.line + 1}); "
                "allowed: aliases of finished values, no recursive structures"
            )
        on_path.add(key)
        if len(on_path) > MAX_YAML_DEPTH:
            raise YamlLimitError(
                f"nested more than {MAX_YAML_DEPTH} levels deep (line "
                f"{node.start_mark.line + 1}); allowed: at most {MAX_YAML_DEPTH} levels"
            )
        stack.append((node, True))
        stack.extend((child, False) for child in _children(node))


class _YamlLoader(yaml.SafeLoader):
    """PyYAML's safe loader that also reads ``1e-4`` as a float and rejects duplicate keys.

    PyYAML follows YAML 1.1, where a float needs a dot (``1.0e-4``) and ``1e-4`` is the string
    ``"1e-4"``; config values would then fail validation with a confusing message. A mapping
    that repeats a key (a second ``episode:`` section) raises :class:`DuplicateKeyError`
    instead of silently dropping the first; keys brought in by a ``<<`` merge may be
    overridden as YAML intends. The composed document is checked by
    :func:`check_node_graph` before any Python object is built from it.
    """

    def get_single_node(self) -> Any:
        node = super().get_single_node()
        if node is not None:
            check_node_graph(node)
        return node

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
        yaml.YAMLError: Malformed YAML; :class:`DuplicateKeyError` for a repeated key;
            :class:`YamlLimitError` for a document beyond the size or depth limits.
    """
    try:
        return yaml.load(text, Loader=_YamlLoader)  # a SafeLoader subclass: no arbitrary objects
    except RecursionError:  # PyYAML's parser recurses per level, before the node check
        raise YamlLimitError(
            f"nested too deeply; allowed: at most {MAX_YAML_DEPTH} levels"
        ) from None


def _mib(size: int) -> str:
    """``size`` in bytes for a message: ``512 bytes``, ``1 MiB``, ``3 GiB``."""
    if size < 1024:
        return f"{size:,} bytes"
    units = ("KiB", "MiB", "GiB", "TiB")
    value, index = size / 1024, 0
    while value >= 1024 and index < len(units) - 1:
        value /= 1024
        index += 1
    return f"{value:.3g} {units[index]}"


def check_config_file(path: Path, what: str = "scenario file") -> os.stat_result:
    """Check a configuration file before reading it: it exists, is not a folder or a device,
    and a regular file's size is at most :data:`MAX_CONFIG_BYTES`.

    A FIFO (``<(cat scenario.yaml)``) passes: :func:`read_text_file` reads at most the cap
    from it.

    Raises:
        ConfigError: The message names the file, the problem and what is allowed.
    """
    try:
        st = os.stat(path)
    except OSError as exc:
        raise ConfigError(f"{what} {str(path)[:200]!r}: cannot be read ({exc.strerror})") from None
    if stat.S_ISDIR(st.st_mode):
        raise ConfigError(f"{what} {str(path)!r}: is a folder; allowed: a YAML file")
    if not (stat.S_ISREG(st.st_mode) or stat.S_ISFIFO(st.st_mode)):
        kind = "a character device" if stat.S_ISCHR(st.st_mode) else "not a regular file"
        raise ConfigError(f"{what} {str(path)!r}: is {kind}; allowed: a YAML file")
    if stat.S_ISREG(st.st_mode) and st.st_size > MAX_CONFIG_BYTES:
        raise ConfigError(
            f"{what} {str(path)!r}: {_mib(st.st_size)}; allowed: at most {_mib(MAX_CONFIG_BYTES)}"
        )
    return st


def read_text_file(path: Path, what: str = "scenario file") -> str:
    """A UTF-8 text file's content (at most :data:`MAX_CONFIG_BYTES`), with errors that name
    the file.

    Raises:
        ConfigError: The file cannot be read, is a folder or a device, is larger than the
            cap, or is not UTF-8 text.
    """
    check_config_file(path, what)
    try:
        with open(path, "rb") as fh:
            data = fh.read(MAX_CONFIG_BYTES + 1)  # a file that grew, or a pipe: never more
    except OSError as exc:
        raise ConfigError(f"{what} {str(path)!r}: cannot be read ({exc.strerror})") from exc
    if len(data) > MAX_CONFIG_BYTES:
        raise ConfigError(
            f"{what} {str(path)!r}: more than {_mib(MAX_CONFIG_BYTES)}; allowed: at most "
            f"{_mib(MAX_CONFIG_BYTES)}"
        )
    try:
        return data.decode("utf-8")
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
    except (DuplicateKeyError, YamlLimitError) as exc:
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
