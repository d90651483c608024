"""Class table (config/classes.yaml) loading, validation and lookups."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from cad_replacement.cad import CLASS_BUILDERS
from recon_core.classes import DEFAULT_CLASS_TABLE, UNKNOWN_CLASS_ID, load_class_table
from recon_core.errors import ConfigError, UnknownClassError


def test_table_loads_and_covers_all_cad_classes() -> None:
    table = load_class_table()
    assert set(CLASS_BUILDERS) <= set(table.names)
    assert {"floor", "wall", "ceiling"} <= set(table.names)
    for c in table.of_category("layout"):
        assert not c.is_thing and not c.movable and c.density is None
    for name in CLASS_BUILDERS:
        info = table.by_name(name)
        expected = "articulated" if CLASS_BUILDERS[name].articulated else "rigid"
        assert info.category == expected and info.density and info.density > 0
    assert UNKNOWN_CLASS_ID not in [c.id for c in table]


def test_lookups() -> None:
    table = load_class_table()
    fridge = table.by_name("fridge")
    assert table.by_id(fridge.id) is fridge
    assert fridge.is_articulated and not fridge.movable
    assert table.from_coco("refrigerator") is fridge
    assert table.from_coco("dining table").name == "table"
    assert table.from_coco("couch").name == "sofa"
    assert table.from_coco("tv").name == "monitor"
    assert {table.from_coco(n).name for n in ("handbag", "backpack", "suitcase")} == {"bag"}
    assert table.get_by_coco("giraffe") is None
    assert table.by_name("cup").movable and table.by_name("chair").movable
    assert not table.by_name("table").movable
    assert "desk" in table.by_name("table").confusable_with
    assert {"wardrobe", "dishwasher", "shelf"} <= set(table.by_name("cabinet").confusable_with)
    assert "bottle" in table.by_name("cup").confusable_with
    assert table.by_name("cup").round and table.by_name("bottle").round and not table.by_name("book").round
    assert table.id_of("unknown") == UNKNOWN_CLASS_ID
    with pytest.raises(UnknownClassError, match="unknown class name 'spaceship'"):
        table.by_name("spaceship")
    with pytest.raises(UnknownClassError, match="reserved"):
        table.by_id(UNKNOWN_CLASS_ID)
    with pytest.raises(UnknownClassError, match="giraffe"):
        table.from_coco("giraffe")


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (lambda d: d["classes"].append(dict(d["classes"][0])), "duplicate"),
        (lambda d: d["classes"][0].update(id=-1), "id"),
        (lambda d: d["classes"][0].update(category="gas"), "category"),
        (lambda d: d["classes"][5].update(density=None), "density"),
        (lambda d: d["classes"][0].pop("coco"), "missing keys"),
        (lambda d: d["classes"][4].update(coco=["chair"]), "several classes"),
        (lambda d: d["confusion_groups"].append(["table", "spaceship"]), "unknown classes"),
        (lambda d: d.update(extra=1), "unknown keys"),
        (lambda d: d["classes"][5].update(round="yes"), "round must be true/false"),
        (lambda d: d["classes"][5].update(roundish=True), "unknown keys"),
    ],
)
def test_invalid_tables_are_rejected(tmp_path: Path, edit, message: str) -> None:
    data = yaml.safe_load(DEFAULT_CLASS_TABLE.read_text())
    edit(data)
    path = tmp_path / "classes.yaml"
    path.write_text(yaml.safe_dump(data))
    with pytest.raises(ConfigError, match=message):
        load_class_table(path)


def test_unreadable_files(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="cannot read"):
        load_class_table(tmp_path / "missing.yaml")
    bad = tmp_path / "bad.yaml"
    bad.write_text("classes: [unclosed")
    with pytest.raises(ConfigError, match="invalid YAML"):
        load_class_table(bad)


def test_generic_object_class_has_no_cad_model_and_stays_observed(tmp_path: Path) -> None:
    """Detector classes without a class of their own map to `object`: a rigid movable thing with a
    density but no procedural CAD builder, so CAD replacement keeps its observed mesh."""
    from cad_replacement.cad import CadLibrary
    from cad_replacement.matching import candidate_classes
    from recon_core.classes import GENERIC_CLASS_NAME

    table = load_class_table()
    obj = table.by_name(GENERIC_CLASS_NAME)
    assert obj.category == "rigid" and obj.is_thing and obj.movable and obj.density and obj.density > 0
    assert obj.coco_names == () and GENERIC_CLASS_NAME not in CLASS_BUILDERS
    assert candidate_classes(GENERIC_CLASS_NAME, table) == [GENERIC_CLASS_NAME]
    lib = CadLibrary(cache_dir=tmp_path, seeds_per_class=1, class_table=table)
    assert lib.candidates(GENERIC_CLASS_NAME) == [] and GENERIC_CLASS_NAME not in lib.class_names
