"""The one config validator: field rules checked on load, on construction and on whole trees."""

from __future__ import annotations

from dataclasses import dataclass, field

import pytest

from recon_core.config import (
    ConfigError,
    Settings,
    build_config,
    flatten,
    from_dict,
    iter_settings,
    load_config,
    setting,
    to_dict,
    validate,
)


@dataclass
class _Inner(Settings):
    share: float = setting(0.5, min=0.0, max=1.0, doc="a fraction")
    size: int = setting(3, min=0, min_exclusive=True)
    offsets: list[int] = setting([1, 2], min=1)


@dataclass
class _Outer(Settings):
    mode: str = setting("full", choices=("full", "baseline"))
    trim: float = setting(0.0, min=0.0, max=50.0, max_exclusive=True)
    enabled: bool = True
    inner: _Inner = field(default_factory=_Inner)
    levels: dict[str, _Inner] = field(default_factory=lambda: {"low": _Inner(share=0.1), "high": _Inner()})


@dataclass
class _Pair(Settings):
    bounds: list[float] = field(default_factory=lambda: [1.0, 2.0])

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.bounds[0] > self.bounds[1]:
            raise ConfigError(f"bounds must be [min, max], got {self.bounds}")


@dataclass
class _HasPair(Settings):
    pair: _Pair = field(default_factory=_Pair)


@pytest.mark.parametrize(("data", "message"), [
    ({"inner": {"share": 1.5}}, r"^inner\.share: got 1\.5; allowed: in \[0, 1\]$"),
    ({"inner": {"size": 0}}, r"^inner\.size: got 0; allowed: > 0$"),
    ({"inner": {"offsets": [1, 0]}}, r"^inner\.offsets\[1\]: got 0; allowed: >= 1$"),
    ({"trim": 50}, r"^trim: got 50; allowed: in \[0, 50\)$"),
    ({"mode": "fast"}, r"^mode: got 'fast'; valid values: \['full', 'baseline'\]$"),
    ({"levels": {"high": {"share": -0.1}}}, r"^levels\.high\.share: got -0\.1; allowed: in \[0, 1\]$"),
])
def test_out_of_range_values_are_rejected_naming_the_dotted_key_and_the_range(data, message):
    with pytest.raises(ConfigError, match=message):
        from_dict(_Outer, data)


@pytest.mark.parametrize(("data", "message"), [
    ({"inner": {"share": True}}, r"inner\.share: expected a number"),
    ({"inner": {"size": 2.5}}, r"inner\.size: expected an integer"),
    ({"inner": {"size": False}}, r"inner\.size: expected an integer"),
    ({"enabled": 1}, r"enabled: expected true/false"),
    ({"mode": 3}, r"mode: expected a string"),
    ({"inner": {"offsets": "1, 2"}}, r"inner\.offsets: expected a list"),
])
def test_wrong_types_are_rejected_naming_the_key(data, message):
    with pytest.raises(ConfigError, match=message):
        from_dict(_Outer, data)


def test_an_int_is_accepted_for_a_float_and_becomes_one():
    cfg = from_dict(_Outer, {"inner": {"share": 1}, "trim": 10})
    assert cfg.inner.share == 1.0 and isinstance(cfg.inner.share, float)
    assert isinstance(cfg.trim, float)


def test_construction_in_code_checks_the_same_rules():
    with pytest.raises(ConfigError, match=r"_Inner\.share: got 2; allowed: in \[0, 1\]"):
        _Inner(share=2)
    with pytest.raises(ConfigError, match="valid values"):
        _Outer(mode="fast")
    a, b = _Inner(), _Inner()
    a.offsets.append(5)
    assert b.offsets == [1, 2]  # a list default is copied per instance


def test_validate_catches_values_assigned_after_construction():
    cfg = _Outer()
    validate(cfg)
    cfg.levels["low"].share = 3.0
    with pytest.raises(ConfigError, match=r"^levels\.low\.share: got 3"):
        validate(cfg)
    cfg = _Outer()
    cfg.inner.size = "big"
    with pytest.raises(ConfigError, match=r"^inner\.size: expected an integer"):
        validate(cfg)


def test_cross_field_conditions_stay_in_post_init_and_name_where_the_object_sits():
    with pytest.raises(ConfigError, match=r"^pair: bounds must be \[min, max\]"):
        from_dict(_HasPair, {"pair": {"bounds": [3, 1]}})
    cfg = _HasPair()
    cfg.pair.bounds = [5.0, 1.0]
    with pytest.raises(ConfigError, match=r"^pair: bounds must be"):
        validate(cfg)


def test_load_config_checks_the_file_and_the_overrides(tmp_path):
    path = tmp_path / "c.yaml"
    path.write_text("inner:\n  share: 0.25\nlevels:\n  high: {size: 7}\n")
    cfg = load_config(_Outer, path, {"trim": 2})
    assert (cfg.inner.share, cfg.levels["high"].size, cfg.trim) == (0.25, 7, 2.0)
    with pytest.raises(ConfigError, match=r"inner\.size: got -1"):
        load_config(_Outer, path, {"inner.size": -1})
    path.write_text("inner:\n  share: 7\n")
    with pytest.raises(ConfigError, match=r"^inner\.share: got 7"):
        load_config(_Outer, path)


def test_iter_settings_walks_the_keys_flatten_gives_with_types_and_rules():
    cfg = build_config(_Outer, {}, {"levels.low.size": 4})
    infos = {s.key: s for s in iter_settings(cfg)}
    assert list(infos) == list(flatten(to_dict(cfg)))
    assert infos["levels.low.size"].value == 4
    assert infos["inner.share"].annotation is float
    assert infos["inner.share"].rule.describe() == "in [0, 1]"
    assert infos["inner.share"].rule.doc == "a fraction"
    assert infos["enabled"].rule is None


def test_the_stage_configs_keep_their_ranges():
    from panoptic_mapping.config import MapperConfig
    from panoptic_mapping.segmentation.config import SegmentationConfig
    from scene_graph.config import SceneGraphConfig

    for cls, overrides, message in [
        (MapperConfig, {"downsample": 0}, r"downsample: got 0; allowed: >= 1"),
        (MapperConfig, {"mode": "fancy"}, r"mode: got 'fancy'; valid values"),
        (SceneGraphConfig, {"support.a_th": 0.5}, r"support\.a_th: got 0\.5; allowed: in \[-1, 0\]"),
        (SceneGraphConfig, {"box.trim_percent": 50.0}, r"box\.trim_percent: got 50; allowed: in \[0, 50\)"),
        (SceneGraphConfig, {"support.distance_scale": 0}, r"support\.distance_scale: got 0; allowed: > 0"),
        (SceneGraphConfig, {"proximal.broadphase": "octree"}, r"proximal\.broadphase: got 'octree'"),
        (SegmentationConfig, {"oracle.levels.hard.flicker": 1.5}, r"oracle\.levels\.hard\.flicker: got 1\.5"),
        (SegmentationConfig, {"oracle.levels.clean.paint.min_area_px": -1},
         r"oracle\.levels\.clean\.paint\.min_area_px: got -1; allowed: >= 0"),
        (SegmentationConfig, {"oracle.levels.hard.reference_height_px": 0}, r"reference_height_px: got 0"),
        (SegmentationConfig, {"oracle.levels.hard.spurious_axes_px": [9.0, 1.0]},
         r"oracle\.levels\.hard: spurious_axes_px must be \[min, max\]"),
    ]:
        with pytest.raises(ConfigError, match=message):
            build_config(cls, {}, overrides)
    assert build_config(SceneGraphConfig, {}, {"support.a_th": -1}).support.a_th == -1.0
