"""The interval notation of vio_core.ranges and the walk over a settings tree."""

import math
from dataclasses import dataclass, field

import pytest

from vio_core.errors import SettingsError
from vio_core.ranges import Interval, check_ranges


def test_interval_notation():
    positive = Interval.parse("(0, inf)")
    assert 1e300 in positive and 0.0 not in positive and math.inf not in positive and math.nan not in positive
    assert math.inf in Interval.parse("(0, inf]")
    unit = Interval.parse("[0, 1]")
    assert 0 in unit and 1 in unit and 1.0000001 not in unit and True not in unit
    assert positive.describe() == "finite and > 0" and unit.describe() == "in [0, 1]"
    with pytest.raises(ValueError):
        Interval.parse("0..1")


@dataclass(frozen=True)
class Inner:
    sigma: float = 1.0
    pair: tuple[float, float] = (0.2, 0.8)


@dataclass(frozen=True)
class Outer:
    threshold: float = 2.0
    count: int = 3
    inner: Inner = field(default_factory=Inner)


TABLE = {"Inner.sigma": "(0, inf)", "Inner.pair": "[0, 1]", "Outer.count": "[1, inf)"}


@pytest.mark.parametrize("settings, message", [
    (Outer(inner=Inner(sigma=math.inf)), "inner.sigma must be finite and > 0, got inf"),
    (Outer(inner=Inner(sigma=-1.0)), "inner.sigma must be finite and > 0, got -1.0"),
    (Outer(inner=Inner(pair=(0.2, 1.5))), r"inner.pair must be in \[0, 1\], got \(0.2, 1.5\)"),
    (Outer(count=0), "count must be finite and >= 1, got 0"),
    (Outer(threshold=math.inf), "threshold must be finite"),  # no entry: finite
])
def test_check_ranges_names_the_key_path(settings, message):
    check_ranges(Outer(), TABLE)
    with pytest.raises(SettingsError, match=message):
        check_ranges(settings, TABLE)
