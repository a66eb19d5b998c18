"""Settings machinery: presets by name, typed overrides with key paths, plain-dict and TOML round trips."""

from dataclasses import dataclass, field

import pytest

from vio_core import Presets, SettingsError, UnknownNameError, override, to_plain, toml_dumps, toml_loads


@dataclass(frozen=True)
class Inner:
    sigma: float = 1.0
    window: tuple[float, float] = (0.25, 0.75)

    def __post_init__(self):
        if not self.sigma > 0:
            raise SettingsError(f"sigma must be > 0, got {self.sigma}")


@dataclass(frozen=True)
class Outer:
    name: str = "a"
    count: int = 3
    enabled: bool = True
    inner: Inner = field(default_factory=Inner)
    optional: Inner | None = None


def test_override_converts_validates_and_names_the_key_path():
    s = override(Outer(), {"count": 5, "inner": {"sigma": 2, "window": [0.1, 0.9]}, "optional": True})
    assert s == Outer(count=5, inner=Inner(2.0, (0.1, 0.9)), optional=Inner())
    assert isinstance(s.inner.sigma, float) and isinstance(s.inner.window, tuple)
    assert override(s, optional=False).optional is None
    with pytest.raises(SettingsError, match=r"unknown setting outer\.cuont; valid: count, enabled"):
        override(Outer(), {"cuont": 1}, where="outer")
    with pytest.raises(SettingsError, match=r"outer\.inner\.sigma: expected a number"):
        override(Outer(), {"inner": {"sigma": "big"}}, where="outer")
    with pytest.raises(SettingsError, match=r"NaN"):
        override(Inner(), sigma=float("nan"))
    with pytest.raises(SettingsError, match=r"sigma must be > 0"):  # the class's own validation
        override(Outer(), {"inner": {"sigma": -1.0}})
    with pytest.raises(SettingsError, match="integer"):
        override(Outer(), count=2.5)
    with pytest.raises(SettingsError, match="true or false"):
        override(Outer(), enabled="yes")


def test_presets_by_name_with_overrides_and_name_of():
    presets = Presets("thing", {"small": Inner(0.5), "big": Inner(5.0)}, default="small",
                      descriptions={"big": "a big one"})
    assert presets["big"].sigma == 5.0 and presets.describe("big") == "a big one"
    assert presets.get_preset(window=(0.0, 1.0)) == Inner(0.5, (0.0, 1.0))
    with pytest.raises(UnknownNameError, match="big, small"):
        presets["huge"]
    assert isinstance(UnknownNameError("a", "b", []), ValueError)
    assert presets.name_of(Inner(4.0)) == "small"  # a tie (one differing field each): the first preset
    assert presets.name_of(Inner(5.0, (0.1, 0.2))) == "big"  # fewest differing fields
    assert presets.name_of(Outer()) is None


def test_plain_dict_and_toml_round_trip():
    s = Outer(name='say "hi"', inner=Inner(0.125), optional=None)
    plain = to_plain(s)
    assert plain["optional"] is False and plain["inner"]["window"] == [0.25, 0.75]
    back = override(Outer(), toml_loads(toml_dumps(plain)))
    assert back == s
    with pytest.raises(SettingsError, match="invalid TOML"):
        toml_loads("x = = 1", "cfg.toml")


def test_require_positive_names_the_class_and_field():
    from dataclasses import dataclass

    from vio_core import require_positive

    @dataclass
    class Knobs:
        a: float = 1.0
        b: float = 2.0

    require_positive(Knobs(), "a", "b")
    with pytest.raises(SettingsError, match=r"Knobs\.b must be finite and > 0, got 0\.0"):
        require_positive(Knobs(b=0.0), "a", "b")
    with pytest.raises(SettingsError, match="Knobs.a"):
        require_positive(Knobs(a=float("nan")), "a", finite=False)
    with pytest.raises(SettingsError, match="Knobs.a"):
        require_positive(Knobs(a=float("inf")), "a")
    require_positive(Knobs(a=float("inf")), "a", finite=False)
