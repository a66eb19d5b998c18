"""Settings machinery shared by every stage: named presets, field overrides, plain-dict round trips.

Every stage's settings are a frozen dataclass that validates itself in ``__post_init__``
(raising :class:`~vio_core.errors.SettingsError`). This module adds what all of them need:

* :class:`Presets`: the named presets of one family (``"sift"``, ``"disk+lightglue"``...),
  chosen by name with an :class:`~vio_core.errors.UnknownNameError` listing the valid ones;
* :func:`override`: a new settings object with some fields replaced, from keyword
  arguments or a nested plain dict (a TOML table), type-checked field by field, with
  errors that name the key path (``rescaler.ransac.inlier_sigmas``);
* :func:`to_plain`: the nested plain dict of a settings object (JSON / TOML ready).

Optional nested settings (a field typed ``X | None`` whose value is a dataclass ``X``) are
written as ``false`` when None; when reading, ``false`` means None, ``true`` the default
``X()`` and a table overrides ``X()``'s fields.
"""

from __future__ import annotations

import dataclasses
import math
import types
import typing
from typing import Any, Callable, Generic, Iterator, Mapping, TypeVar

from .errors import SettingsError, lookup
from .limits import MAX_NESTING, nesting_depth, value_depth

try:
    import tomllib  # Python >= 3.11
except ModuleNotFoundError:  # pragma: no cover - Python 3.10 (tomli is a dependency there)
    import tomli as tomllib

T = TypeVar("T")


class Presets(Mapping[str, T], Generic[T]):
    """The named presets of one settings family.

    Args:
        family: what the presets are of, for messages ("matcher", "pairing preset").
        presets: name -> settings object (a frozen dataclass instance).
        default: the name used when none is given.
        descriptions: optional name -> one-line description (``vio-depth presets``).
    """

    def __init__(self, family: str, presets: dict[str, T], default: str, descriptions: dict[str, str] | None = None):
        if default not in presets:
            raise SettingsError(f"{family}: default preset {default!r} is not among {sorted(presets)}")
        self.family = family
        self._presets = dict(presets)
        self.default = default
        self.descriptions = dict(descriptions or {})

    def __getitem__(self, name: str) -> T:
        return lookup(self.family, name, self._presets)

    def __iter__(self) -> Iterator[str]:
        return iter(self._presets)

    def __len__(self) -> int:
        return len(self._presets)

    def get_preset(self, name: str | None = None, **overrides) -> T:
        """Preset ``name`` (default: :attr:`default`) with field ``overrides`` (None values ignored)."""
        base = self[self.default if name is None else name]
        return override(base, {k: v for k, v in overrides.items() if v is not None}, where=self.family)

    def name_of(self, value, key: Callable[[Any], Any] = type) -> str | None:
        """The name of the preset ``value`` derives from: among the presets with the same
        ``key`` (by default: the same settings type), the one with the fewest differing fields;
        None when no preset has that key."""
        best, fewest = None, None
        for name, preset in self._presets.items():
            if key(preset) != key(value):
                continue
            differ = sum(getattr(preset, f.name) != getattr(value, f.name) for f in dataclasses.fields(preset))
            if fewest is None or differ < fewest:
                best, fewest = name, differ
        return best

    def describe(self, name: str) -> str:
        return self.descriptions.get(name, "")


# --------------------------------------------------------------------------- overrides
def require_positive(settings, *names: str, finite: bool = True) -> None:
    """Raise :class:`SettingsError` naming the first of the fields ``names`` of ``settings``
    (a settings dataclass) that is not > 0 (and, with ``finite``, not finite)."""
    for name in names:
        v = getattr(settings, name)
        if not (v > 0 and (not finite or math.isfinite(v))):
            what = "finite and > 0" if finite else "> 0"
            raise SettingsError(f"{type(settings).__name__}.{name} must be {what}, got {v!r}")


def _field_types(cls) -> dict[str, Any]:
    return typing.get_type_hints(cls)


def _is_optional(tp) -> tuple[bool, Any]:
    """(True, X) for ``X | None`` / ``Optional[X]``, else (False, tp)."""
    origin = typing.get_origin(tp)
    if origin in (typing.Union, types.UnionType):
        args = [a for a in typing.get_args(tp) if a is not type(None)]
        if len(args) < len(typing.get_args(tp)):
            return True, (args[0] if len(args) == 1 else typing.Union[tuple(args)])
    return False, tp


def _convert(value, tp, path: str, current):
    """``value`` (from a dict / TOML / keyword) converted to the field type ``tp``."""
    optional, inner = _is_optional(tp)
    if value is None:
        if optional:
            return None
        raise SettingsError(f"{path}: a value is required")
    # nested settings: a table overrides the current (or default) object's fields
    union_args = typing.get_args(inner) if typing.get_origin(inner) in (typing.Union, types.UnionType) else ()
    if dataclasses.is_dataclass(inner) or (union_args and all(dataclasses.is_dataclass(a) for a in union_args)):
        if dataclasses.is_dataclass(value) and not isinstance(value, type):
            return value
        if optional and isinstance(value, bool):
            if not value:
                return None
            base = current if current is not None else inner()
            return base
        if isinstance(value, Mapping):
            base = current if current is not None else inner()
            return override(base, value, where=path)
        raise SettingsError(f"{path}: expected a table of settings, got {value!r}")
    if inner is Any:
        return value
    if inner is bool:
        if isinstance(value, bool):
            return value
        raise SettingsError(f"{path}: expected true or false, got {value!r}")
    if inner is int:
        if isinstance(value, bool) or not isinstance(value, int):
            if isinstance(value, float) and value.is_integer():
                return int(value)
            raise SettingsError(f"{path}: expected an integer, got {value!r}")
        return value
    if inner is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise SettingsError(f"{path}: expected a number, got {value!r}")
        value = float(value)
        if math.isnan(value):
            raise SettingsError(f"{path}: NaN is not a valid setting")
        return value
    if inner is str:
        if not isinstance(value, str):
            raise SettingsError(f"{path}: expected a string, got {value!r}")
        return value
    origin = typing.get_origin(inner)
    if origin is tuple:
        if not isinstance(value, (list, tuple)):
            raise SettingsError(f"{path}: expected a list, got {value!r}")
        args = typing.get_args(inner)
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(_convert(v, args[0], f"{path}[{i}]", None) for i, v in enumerate(value))
        if len(args) != len(value):
            raise SettingsError(f"{path}: expected {len(args)} values, got {len(value)}")
        return tuple(_convert(v, a, f"{path}[{i}]", None) for i, (v, a) in enumerate(zip(value, args)))
    if isinstance(inner, type) and isinstance(value, inner):
        return value
    if isinstance(inner, type) and issubclass(inner, str) and isinstance(value, str):  # str enums
        try:
            return inner(value)
        except ValueError:
            raise SettingsError(f"{path}: {value!r} is not one of {[m.value for m in inner]}") from None
    raise SettingsError(f"{path}: cannot use {value!r} for a setting of type {inner}")


def override(settings: T, changes: Mapping[str, Any] | None = None, where: str = "", **kwargs) -> T:
    """A copy of the frozen dataclass ``settings`` with fields replaced.

    Args:
        settings: a frozen dataclass instance.
        changes: field name -> new value; nested settings take a mapping of their own fields.
        where: the key path of ``settings`` for messages (``"rescaler"``).
        **kwargs: more changes.

    Raises:
        SettingsError: an unknown field (lists the valid ones), a value of the wrong type,
            or a value the settings' own validation refuses (each names the key path).
    """
    changes = {**(changes or {}), **kwargs}
    if not changes:
        return settings
    cls = type(settings)
    types_ = _field_types(cls)
    names = [f.name for f in dataclasses.fields(cls) if f.init]
    prefix = f"{where}." if where else ""
    new = {}
    for key, value in changes.items():
        if key not in names:
            raise SettingsError(f"unknown setting {prefix}{key}; valid: {', '.join(sorted(names))}")
        new[key] = _convert(value, types_[key], prefix + key, getattr(settings, key))
    try:
        return dataclasses.replace(settings, **new)
    except SettingsError as exc:
        raise SettingsError(f"{where}: {exc}" if where else str(exc)) from None
    except (TypeError, ValueError) as exc:
        raise SettingsError(f"{where or cls.__name__}: {exc}") from None


def to_plain(settings) -> dict[str, Any]:
    """Nested plain dict of a settings dataclass: tuples become lists, str enums their value,
    a None nested settings object ``False``, other None values are left out."""
    out: dict[str, Any] = {}
    types_ = _field_types(type(settings))
    for f in dataclasses.fields(settings):
        value = getattr(settings, f.name)
        if dataclasses.is_dataclass(value):
            out[f.name] = to_plain(value)
        elif value is None:
            optional, inner = _is_optional(types_[f.name])
            if optional and dataclasses.is_dataclass(inner):
                out[f.name] = False
        elif isinstance(value, tuple):
            out[f.name] = [v.value if isinstance(v, str) and hasattr(v, "value") else v for v in value]
        elif isinstance(value, str) and hasattr(value, "value"):
            out[f.name] = value.value
        else:
            out[f.name] = value
    return out


# --------------------------------------------------------------------------- TOML
_TOML_ESCAPES = {"\\": "\\\\", '"': '\\"', "\b": "\\b", "\t": "\\t", "\n": "\\n", "\f": "\\f", "\r": "\\r"}


def _toml_string(v: str) -> str:
    """A TOML basic string: quotes, backslashes and control characters escaped.

    Raises:
        SettingsError: ``v`` holds a lone surrogate (a path with bytes that are not UTF-8),
            which TOML cannot represent.
    """
    out = []
    for ch in v:
        code = ord(ch)
        if 0xD800 <= code <= 0xDFFF:
            raise SettingsError(f"cannot write {v!r} to TOML: it holds bytes that are not UTF-8")
        if ch in _TOML_ESCAPES:
            out.append(_TOML_ESCAPES[ch])
        elif code < 0x20 or code == 0x7F:
            out.append(f"\\u{code:04x}")
        else:
            out.append(ch)
    return '"' + "".join(out) + '"'


def toml_dumps(data: Mapping[str, Any]) -> str:
    """TOML text of a nested plain dict (scalars, lists of scalars, nested tables)."""
    lines: list[str] = []

    def scalar(v) -> str:
        if isinstance(v, bool):
            return "true" if v else "false"
        if isinstance(v, int):
            return str(v)
        if isinstance(v, float):
            if math.isinf(v):
                return "inf" if v > 0 else "-inf"
            return repr(v)
        if isinstance(v, str):
            return _toml_string(v)
        if isinstance(v, (list, tuple)):
            return "[" + ", ".join(scalar(x) for x in v) + "]"
        raise SettingsError(f"cannot write {v!r} to TOML")

    def table(prefix: str, d: Mapping[str, Any]) -> None:
        plain = {k: v for k, v in d.items() if not isinstance(v, Mapping)}
        nested = {k: v for k, v in d.items() if isinstance(v, Mapping)}
        if prefix and (plain or not nested):
            lines.append(f"\n[{prefix}]")
        for k, v in plain.items():
            lines.append(f"{k} = {scalar(v)}")
        for k, v in nested.items():
            table(f"{prefix}.{k}" if prefix else k, v)

    table("", data)
    return "\n".join(lines).lstrip("\n") + "\n"


def toml_loads(text: str, source: str = "<string>") -> dict[str, Any]:
    """Parse TOML text (``tomllib``; ``tomli`` on Python 3.10), errors as :class:`SettingsError`.

    The nesting depth is checked before parsing (``tomllib`` recurses once per level: a file
    nested 50 000 arrays deep ended in a ``RecursionError`` with 3 000 lines of traceback) and
    after it (dotted keys and table headers nest without brackets); at most
    :data:`vio_core.limits.MAX_NESTING` levels.
    """
    depth = nesting_depth(text, "toml")
    if depth > MAX_NESTING:
        raise SettingsError(f"{source}: nested {depth} levels deep, more than the {MAX_NESTING} vio-depth reads")
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise SettingsError(f"{source}: invalid TOML: {exc}") from None
    except RecursionError:  # pragma: no cover - the depth check comes first
        raise SettingsError(f"{source}: nested more than the {MAX_NESTING} levels vio-depth reads") from None
    if value_depth(data) > MAX_NESTING:
        raise SettingsError(f"{source}: nested more than the {MAX_NESTING} levels vio-depth reads")
    return data
