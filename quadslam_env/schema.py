"""Validated field specs for the scenario sections of :mod:`quadslam_env.config` and the
estimators' ``estimator.params``.

Every setting is a dataclass field declared with :func:`spec`, which stores its kind, range,
choices and a short description in the field's metadata. :class:`Section` turns a plain mapping
into the frozen dataclass through :func:`coerce`, and :func:`field_rows` reads the same metadata
back for the documentation, so the documented settings cannot drift from the validated ones.
"""

from __future__ import annotations

import copy
import math
from collections.abc import Callable
from dataclasses import MISSING, dataclass, field, fields
from decimal import Decimal
from typing import Any, ClassVar

import numpy as np


class ConfigError(ValueError):
    """Invalid configuration: the message names the key, the value and what is allowed."""


def spec(
    default: Any = None,
    *,
    kind: str = "float",
    lo: float | None = None,
    hi: float | None = None,
    lo_open: bool = False,
    length: int | tuple[int, ...] | None = None,
    max_length: int | None = None,
    choices: tuple[str, ...] | None = None,
    optional: bool = False,
    allow_inf: bool = False,
    doc: str = "",
) -> Any:
    """Declare a validated field.

    Args:
        default: Default value (lists and mappings are copied per instance).
        kind: ``float``, ``int``, ``bool``, ``str``, ``vec`` (list of numbers), ``vecs`` (list of
            ``[x, y, z]``) or ``dict``.
        lo: Lower bound (inclusive unless ``lo_open``), also per element of a ``vec`` and per
            coordinate of a ``vecs`` point (``hi`` alike).
        hi: Upper bound (inclusive).
        lo_open: Make ``lo`` exclusive.
        length: Required length of a ``vec``, or the allowed lengths; when 1 is allowed, a bare
            number stands for a list of one.
        max_length: Most entries of a ``vec`` (checked before its entries).
        choices: Allowed strings of a ``str`` field.
        optional: Accept ``null`` (``None``).
        allow_inf: Accept ``+inf`` above ``lo`` (a number that turns a threshold off).
        doc: One-line meaning and unit, shown in the documentation.

    Returns:
        A :func:`dataclasses.field` carrying the spec in its metadata.
    """
    meta = {
        "kind": kind,
        "lo": lo,
        "hi": hi,
        "lo_open": lo_open,
        "length": length,
        "max_length": max_length,
        "choices": choices,
        "optional": optional,
        "allow_inf": allow_inf,
        "doc": doc,
    }
    if isinstance(default, list | dict):
        return field(default_factory=_copier(default), metadata=meta)
    return field(default=default, metadata=meta)


def _copier(value: Any) -> Callable[[], Any]:
    """A default factory returning a fresh deep copy of ``value``."""
    return lambda: copy.deepcopy(value)


def describe(meta: dict[str, Any]) -> str:
    """What a field accepts, in words (used by error messages and the docs)."""
    if meta["choices"]:
        return f"one of {list(meta['choices'])}"
    kind = meta["kind"]
    base = {
        "float": "a number",
        "int": "an integer",
        "bool": "true or false",
        "str": "a string",
        "vec": _describe_vec(meta["length"], meta.get("max_length")),
        "vecs": "a list of [x, y, z] lists",
        "dict": "a mapping",
    }[kind]
    rng = []
    if meta["lo"] is not None:
        rng.append(f"{'>' if meta['lo_open'] else '>='} {meta['lo']}")
    if meta["hi"] is not None:
        rng.append(f"<= {meta['hi']}")
    text = base + (f" {' and '.join(rng)}" if rng else "")
    text += " (or .inf)" if meta.get("allow_inf") else ""
    return text + (" or null" if meta["optional"] else "")


def _lengths(length: int | tuple[int, ...] | None) -> tuple[int, ...] | None:
    return (length,) if isinstance(length, int) else length


def _describe_vec(length: int | tuple[int, ...] | None, most: int | None = None) -> str:
    lengths = _lengths(length)
    if not lengths:
        return "a list of numbers" if most is None else f"a list of at most {most} numbers"
    lists = [n for n in lengths if n != 1]
    text = f"a list of {' or '.join(map(str, lists))} numbers" if lists else ""
    return "a number or " + text if 1 in lengths and text else text or "a number"


def _check_number(key: str, value: Any, meta: dict[str, Any]) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise ConfigError(f"{key}: got {shown_value(value)}; allowed: {describe(meta)}")
    try:
        num = float(value)
    except OverflowError:  # an integer beyond any float: out of every range
        raise ConfigError(f"{key}: got {shown_value(value)}; allowed: {describe(meta)}") from None
    lo, hi = meta["lo"], meta["hi"]
    inf_ok = meta.get("allow_inf") and num == math.inf
    bad = (not math.isfinite(num) and not inf_ok) or (
        lo is not None and (num <= lo if meta["lo_open"] else num < lo)
    )
    if bad or (hi is not None and num > hi):
        raise ConfigError(f"{key}: got {shown_value(value)}; allowed: {describe(meta)}")
    return num


_LONGEST_SHOWN = 200
"""Characters of a value's repr an error message shows at most."""


def shown_value(value: Any) -> str:
    """``value`` as an error message prints it: a float as its ``repr`` (``1e+300``), an integer
    of more than 16 digits in ``%g`` form (``1e+300``, not 301 digits), lists and tuples item by
    item, anything else as its ``repr``, cut to :data:`_LONGEST_SHOWN` characters."""
    if isinstance(value, int) and not isinstance(value, bool) and abs(value) >= 10**16:
        try:
            return f"{float(value):g}"
        except OverflowError:  # beyond any float (and maybe beyond int's str limit)
            return f"{Decimal(value).normalize():.6g}"
    if isinstance(value, list | tuple):
        items = ", ".join(shown_value(v) for v in value)
        one = "," if isinstance(value, tuple) and len(value) == 1 else ""
        text = f"[{items}]" if isinstance(value, list) else f"({items}{one})"
    else:
        text = repr(value)
    return text if len(text) <= _LONGEST_SHOWN else f"{text[: _LONGEST_SHOWN - 3]}..."


def coerce(key: str, value: Any, meta: dict[str, Any]) -> Any:
    """Validate one value against its field spec and return it in canonical (immutable) form.

    NumPy scalars and arrays (e.g. a particle count from ``np.arange``) are read as the Python
    numbers and lists they hold.

    Raises:
        ConfigError: The value does not fit the spec (the message names ``key``).
    """
    if isinstance(value, np.generic | np.ndarray):
        value = value.tolist()
    if value is None:
        if meta["optional"]:
            return None
        raise ConfigError(f"{key}: got null; allowed: {describe(meta)}")
    kind = meta["kind"]
    if kind == "float":
        return _check_number(key, value, meta)
    if kind == "int":
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"{key}: got {shown_value(value)}; allowed: {describe(meta)}")
        return int(_check_number(key, value, meta))
    if kind == "bool":
        if not isinstance(value, bool):
            raise ConfigError(f"{key}: got {shown_value(value)}; allowed: {describe(meta)}")
        return value
    if kind == "str":
        if not isinstance(value, str) or (meta["choices"] and value not in meta["choices"]):
            raise ConfigError(f"{key}: got {shown_value(value)}; allowed: {describe(meta)}")
        return value
    if kind == "vec":
        lengths = _lengths(meta["length"])
        if (
            lengths
            and 1 in lengths
            and isinstance(value, int | float)
            and not isinstance(value, bool)
        ):
            value = [value]
        if not isinstance(value, list | tuple) or (lengths and len(value) not in lengths):
            raise ConfigError(f"{key}: got {shown_value(value)}; allowed: {describe(meta)}")
        most = meta.get("max_length")
        if most is not None and len(value) > most:
            raise ConfigError(f"{key}: got {len(value)} entries; allowed: {describe(meta)}")
        return tuple(_check_number(f"{key}[{i}]", v, meta) for i, v in enumerate(value))
    if kind == "vecs":
        if not isinstance(value, list | tuple):
            raise ConfigError(f"{key}: got {shown_value(value)}; allowed: {describe(meta)}")
        point_meta = {**meta, "length": 3}  # lo and hi bound each coordinate
        return tuple(
            coerce(f"{key}[{i}]", p, {**point_meta, "kind": "vec"}) for i, p in enumerate(value)
        )
    if kind == "dict":
        if not isinstance(value, dict):
            raise ConfigError(f"{key}: got {shown_value(value)}; allowed: {describe(meta)}")
        return copy.deepcopy(value)
    raise AssertionError(f"unhandled field kind {kind}")  # pragma: no cover - programming error


class Section:
    """Mixin: build a frozen section dataclass from a plain mapping with validation.

    Subclasses are frozen dataclasses whose fields are declared with :func:`spec`; ``SECTION``
    is the section's key in a scenario and ``PRESETS`` maps a ``preset`` value to the settings
    it stands for.
    """

    SECTION: ClassVar[str] = ""
    PRESETS: ClassVar[dict[str, dict[str, Any]]] = {}
    ONLY_FOR: ClassVar[dict[str, tuple[str, tuple[Any, ...]]]] = {}
    """Settings that only some choices read: ``key -> (selector key, choices that use it)``.
    A key set away from its default while the selector has another value is an error (the
    setting would be silently ignored)."""

    @classmethod
    def from_dict(cls, data: Any) -> Any:
        """Validate ``data`` (a mapping or ``None``) and build the section.

        Raises:
            ConfigError: Unknown key, unknown preset, or an invalid value.
        """
        if data is None:
            data = {}
        if not isinstance(data, dict):
            raise ConfigError(f"{cls.SECTION}: got {data!r}; allowed: a mapping of settings")
        known = {f.name: f for f in fields(cls)}  # type: ignore[arg-type]
        for key in data:
            if key not in known:
                raise ConfigError(f"{cls.SECTION}.{key}: unknown key; allowed: {sorted(known)}")
        merged = dict(data)
        preset = data.get("preset")
        if cls.PRESETS and preset is not None:
            if not isinstance(preset, str) or preset not in cls.PRESETS:
                raise ConfigError(
                    f"{cls.SECTION}.preset: got {preset!r}; allowed: one of {sorted(cls.PRESETS)}"
                )
            merged = {**cls.PRESETS[preset], **data}
        kwargs = {}
        for name, fld in known.items():
            # Defaults go through the same coercion so every stored value is immutable.
            value = merged[name] if name in merged else _default(fld)
            kwargs[name] = coerce(f"{cls.SECTION}.{name}", value, dict(fld.metadata))
        obj = cls(**kwargs)
        obj.validate()
        obj.check_used()
        return obj

    @classmethod
    def defaults(cls) -> dict[str, Any]:
        """Every setting's default in canonical (validated) form."""
        return {
            f.name: coerce(f"{cls.SECTION}.{f.name}", _default(f), dict(f.metadata))
            for f in fields(cls)  # type: ignore[arg-type]
        }

    def check_used(self) -> None:
        """Reject settings that the chosen layout, kind or mode ignores (see ``ONLY_FOR``).

        Raises:
            ConfigError: Names the key, its value, the selector's value and what is allowed.
        """
        if not self.ONLY_FOR:
            return
        defaults = self.defaults()
        for key, (selector, users) in self.ONLY_FOR.items():
            choice = getattr(self, selector)
            value = getattr(self, key)
            if choice not in users and value != defaults[key]:
                shown, default = _listed(value), _listed(defaults[key])
                raise ConfigError(
                    f"{self.SECTION}.{key}: got {shown!r}, which {self.SECTION}.{selector} "
                    f"{choice!r} ignores; allowed: leave it at its default ({default!r}) or "
                    f"set {self.SECTION}.{selector} to one of {[_shown(u) for u in users]}"
                )

    def validate(self) -> None:
        """Cross-field checks; overridden where needed."""


def _shown(choice: Any) -> str:
    """A selector's value as it is written in YAML (``true``, not ``True``)."""
    return str(choice).lower() if isinstance(choice, bool) else str(choice)


def _listed(value: Any) -> Any:
    """Canonical tuples back to (nested) lists, as the user wrote them."""
    return [_listed(v) for v in value] if isinstance(value, tuple) else value


def _default(fld: Any) -> Any:
    factory: Callable[[], Any] | Any = fld.default_factory
    if factory is not MISSING and callable(factory):
        return factory()
    return fld.default


@dataclass(frozen=True)
class FieldRow:
    """One documented setting of a section.

    Attributes:
        key: Dotted key, e.g. ``"episode.duration_s"``.
        default: The default as plain data (``None`` is shown as ``null``).
        allowed: What the validator accepts, in words.
        doc: Meaning and unit (may be empty).
    """

    key: str
    default: Any
    allowed: str
    doc: str


def field_rows(section: type[Section]) -> list[FieldRow]:
    """Every setting of ``section`` with its default, accepted values and meaning."""
    rows = []
    for fld in fields(section):  # type: ignore[arg-type]
        meta = dict(fld.metadata)
        default = _default(fld)
        if isinstance(default, tuple):
            default = list(default)
        doc = meta["doc"]
        if fld.name in section.ONLY_FOR:
            selector, users = section.ONLY_FOR[fld.name]
            doc += f" (read only when {selector} is {' or '.join(map(_shown, users))})"
        rows.append(FieldRow(f"{section.SECTION}.{fld.name}", default, describe(meta), doc))
    return rows
