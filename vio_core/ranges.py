"""Valid ranges of numeric settings, written as intervals and checked in one walk (issue 23).

Every stage's settings dataclass validates some of its own fields; this module adds the one
check that covers **every** numeric field of a settings tree: a table maps
``"ClassName.field"`` to an interval in the usual notation, and :func:`check_ranges` walks
the tree and refuses the first value outside its interval, naming the key path::

    "RansacSettings.inlier_sigmas": "(0, inf)"     # finite and > 0
    "RescalerSettings.max_fallback_error": "(0, inf]"   # inf allowed: no bound
    "KalmanSettings.gate_probability": "(0, 1)"
    "PairingSettings.buffer_size": "[1, inf)"

A bound of ``inf`` in a closed bracket (``inf]``) admits the value ``inf``; an open one
(``inf)``) means "finite". A numeric field **without** an entry must at least be finite
(NaN is refused when a value is parsed, :func:`vio_core.settings.override`). Tuples are
checked element by element.
"""

from __future__ import annotations

import dataclasses
import math
import re
from dataclasses import dataclass
from typing import Iterator, Mapping

from .errors import SettingsError

_INTERVAL = re.compile(r"\s*([\[(])\s*(-?inf|[-+0-9.e]+)\s*,\s*(-?inf|[-+0-9.e]+)\s*([\])])\s*")


@dataclass(frozen=True)
class Interval:
    """``low .. high`` with open or closed ends (``low_closed``, ``high_closed``)."""

    low: float
    high: float
    low_closed: bool
    high_closed: bool
    text: str

    @classmethod
    def parse(cls, text: str) -> "Interval":
        """An interval from its notation (``"(0, inf)"``, ``"[0, 1]"``, ``"[1, inf)"``)."""
        m = _INTERVAL.fullmatch(text)
        if m is None:
            raise ValueError(f"not an interval: {text!r} (expected e.g. '(0, inf)' or '[0, 1]')")
        lo, hi = float(m.group(2)), float(m.group(3))
        if not lo <= hi:
            raise ValueError(f"empty interval {text!r}")
        return cls(lo, hi, m.group(1) == "[", m.group(4) == "]", text.strip())

    def __contains__(self, v) -> bool:
        if isinstance(v, bool) or not isinstance(v, (int, float)) or math.isnan(v):
            return False
        above = v >= self.low if self.low_closed else v > self.low
        below = v <= self.high if self.high_closed else v < self.high
        return above and below

    def describe(self) -> str:
        """Words for messages: ``finite``, ``finite and > 0``, ``in [0, 1]``."""
        if self.low == -math.inf and self.high == math.inf and not (self.low_closed or self.high_closed):
            return "finite"
        if self.high == math.inf and not self.high_closed and self.low != -math.inf:
            return f"finite and {'>=' if self.low_closed else '>'} {self.low:g}"
        return f"in {self.text}"


#: the range of a numeric field that has no entry in the table: any finite number
FINITE = Interval(-math.inf, math.inf, False, False, "(-inf, inf)")


def _numeric(value) -> bool:
    if isinstance(value, tuple):
        return len(value) > 0 and all(_numeric(v) for v in value)
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def numeric_fields(settings, where: str = "") -> Iterator[tuple[str, str, object]]:
    """``(table key "Class.field", key path, value)`` of every numeric (or tuple-of-numbers)
    field in the settings tree ``settings`` (a dataclass instance)."""
    for f in dataclasses.fields(settings):
        value = getattr(settings, f.name)
        path = f"{where}.{f.name}" if where else f.name
        if dataclasses.is_dataclass(value) and not isinstance(value, type):
            yield from numeric_fields(value, path)
        elif _numeric(value):
            yield f"{type(settings).__name__}.{f.name}", path, value


def check_ranges(settings, table: Mapping[str, str], where: str = "") -> None:
    """Refuse the first numeric field of the tree ``settings`` outside its interval in
    ``table`` ("Class.field" -> interval notation; fields without an entry: finite).

    Raises:
        SettingsError: naming the key path, the value and the valid range.
    """
    for key, path, value in numeric_fields(settings, where):
        interval = Interval.parse(table[key]) if key in table else FINITE
        values = value if isinstance(value, tuple) else (value,)
        for v in values:
            if v not in interval:
                shown = value if isinstance(value, tuple) else v
                raise SettingsError(f"{path} must be {interval.describe()}, got {shown!r}")


__all__ = ["FINITE", "Interval", "check_ranges", "numeric_fields"]
