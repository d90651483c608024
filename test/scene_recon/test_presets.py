"""Presets (config/presets/*.yaml): overrides of the stage schemas, selected by `--preset NAME`."""

from __future__ import annotations

import argparse

import pytest

from cad_replacement.replace_config import CadReplacementConfig
from panoptic_mapping.config import MapperConfig
from panoptic_mapping.dataio import DataInputConfig
from recon_core.config import CONFIG_DIR, build_config, load_config, load_preset, preset_names
from recon_core.errors import ConfigError
from scene_graph.config import SceneGraphConfig, load_scene_graph_config
from scene_recon.cli import build_parser, main
from scene_recon.commands.common import data_config_from_args
from scene_recon.commands.map_cmd import mapper_config_from_args

SCHEMAS = {"mapper": (MapperConfig, "mapper.yaml"), "data": (DataInputConfig, "data.yaml"),
           "scene_graph": (SceneGraphConfig, "scene_graph.yaml")}


def test_the_three_presets_exist():
    assert {"fast", "balanced", "accurate"} <= set(preset_names())


@pytest.mark.parametrize("name", ["fast", "balanced", "accurate"])
def test_every_preset_key_is_a_key_of_its_stage_schema(name):
    preset = load_preset(name)
    assert preset is not None and preset.description
    for section, (cls, file) in SCHEMAS.items():
        cfg = load_config(cls, CONFIG_DIR / file, preset.section(section))  # unknown keys/ranges raise here
        for key, value in preset.section(section).items():
            node = cfg
            for part in key.split("."):
                node = getattr(node, part)
            assert node == value, (section, key)
    cad = build_config(CadReplacementConfig, {}, preset.section("cad"))
    for key, value in preset.section("cad").items():
        assert getattr(cad, key) == value


def test_fast_really_does_less_work_than_accurate():
    fast, acc = load_preset("fast"), load_preset("accurate")
    mf = load_config(MapperConfig, CONFIG_DIR / "mapper.yaml", fast.section("mapper"))
    ma = load_config(MapperConfig, CONFIG_DIR / "mapper.yaml", acc.section("mapper"))
    assert mf.downsample > ma.downsample
    assert mf.keyframes.enabled and not ma.keyframes.enabled
    assert not mf.fine_surface.enabled and ma.fine_surface.enabled  # the 5 mm grid of small things
    df = load_config(DataInputConfig, CONFIG_DIR / "data.yaml", fast.section("data"))
    assert df.stride > 1
    cf = build_config(CadReplacementConfig, {}, fast.section("cad"))
    ca = build_config(CadReplacementConfig, {}, acc.section("cad"))
    assert cf.top_k < ca.top_k and cf.align_max_nfev < ca.align_max_nfev and cf.screen_keep < ca.screen_keep


def _map_args(*argv: str) -> argparse.Namespace:
    return build_parser().parse_args(["map", "SRC", "--out", "OUT", *argv])


def test_map_preset_reaches_the_mapper_and_data_configs_and_options_win():
    cfg = mapper_config_from_args(_map_args("--preset", "fast"))
    assert cfg.downsample == 2 and cfg.keyframes.label_every_n_frames == 0
    assert data_config_from_args(_map_args("--preset", "fast")).stride == 2
    assert data_config_from_args(_map_args("--preset", "fast", "--stride", "3")).stride == 3  # the option wins
    cfg = mapper_config_from_args(_map_args("--preset", "fast", "--voxel-size", "0.05"))
    assert cfg.tsdf.voxel_size_m == 0.05 and cfg.downsample == 2
    default = mapper_config_from_args(_map_args())
    assert default.downsample == 1 and data_config_from_args(_map_args()).stride == 1


@pytest.mark.parametrize("command", ["map", "graph", "replace", "run", "demo"])
def test_preset_option_on_the_commands_that_take_configs(command):
    argv = {"map": ["map", "S", "--out", "O"], "graph": ["graph", "S"], "replace": ["replace", "G", "--out", "O"],
            "run": ["run", "S", "--out", "O"], "demo": ["demo"]}[command]
    assert build_parser().parse_args([*argv, "--preset", "accurate"]).preset == "accurate"


def test_graph_preset_uses_the_scene_graph_schema():
    cfg = load_scene_graph_config(None, load_preset("accurate").section("scene_graph"))
    assert cfg.planes.ransac_iterations == 400


def test_unknown_preset_and_bad_keys_are_clear_errors(tmp_path, capsys):
    with pytest.raises(ConfigError, match=r"unknown preset .fastest.*fast"):
        load_preset("fastest")
    bad = tmp_path / "bad.yaml"
    bad.write_text("mapper:\n  tsdf:\n    voxel_size: 0.03\n", encoding="utf-8")
    with pytest.raises(ConfigError, match="voxel_size"):
        mapper_config_from_args(_map_args("--preset", str(bad)))
    bad.write_text("mappr:\n  downsample: 2\n", encoding="utf-8")
    with pytest.raises(ConfigError, match="unknown section"):
        load_preset(str(bad))
    assert main(["graph", str(tmp_path), "--preset", "nope"]) == 2
    assert "unknown preset" in capsys.readouterr().err
