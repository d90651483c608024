"""Import metadata: per-folder and per-URDF files, and the source frame (which way is up)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from cad_replacement.cad.import_meta import ImportMeta, load_model_meta, parse_meta, source_frame
from recon_core.errors import CadImportError


@pytest.mark.parametrize(
    ("meta", "suffixes", "expected"),
    [
        ({}, {".obj", ".stl"}, ("+z", "+x", "urdf")),  # ROS REP 103
        ({}, set(), ("+z", "+x", "urdf")),  # primitives only
        ({}, {".glb"}, ("+y", "+z", "gltf")),  # glTF 2.0: y up, front +z
        ({}, {".glb", ".gltf"}, ("+y", "+z", "gltf")),
        ({"up_axis": "+z"}, {".glb"}, ("+z", "+x", "meta")),
        ({"up_axis": "+y"}, {".glb"}, ("+y", "+z", "meta")),  # the front keeps the glTF convention
        ({"up_axis": "+y"}, {".obj"}, ("+y", "+x", "meta")),
        ({"up_axis": "+x"}, {".obj"}, ("+x", "+z", "meta")),  # +x front would be parallel: next axis
        ({"front_axis": "-x"}, {".dae"}, ("+z", "-x", "urdf")),
        ({"up_axis": "-z", "front_axis": "+y"}, {".glb", ".obj"}, ("-z", "+y", "meta")),  # explicit: no ambiguity
    ],
)
def test_source_frame_rules(meta: dict, suffixes: set[str], expected: tuple[str, str, str]) -> None:
    frame = source_frame(parse_meta(meta), suffixes, "m.urdf")
    assert (frame.up, frame.front, frame.reason) == expected
    rot = frame.rotation()
    axes = {"+x": [1, 0, 0], "-x": [-1, 0, 0], "+y": [0, 1, 0], "-y": [0, -1, 0], "+z": [0, 0, 1], "-z": [0, 0, -1]}
    assert rot @ axes[frame.up] == pytest.approx([0.0, 0.0, 1.0])
    assert rot @ axes[frame.front] == pytest.approx([1.0, 0.0, 0.0])
    assert np.linalg.det(rot) == pytest.approx(1.0)


def test_mixed_formats_and_bad_axes_raise() -> None:
    with pytest.raises(CadImportError, match=r"ambiguous.*\['.obj'\].*up_axis"):
        source_frame(ImportMeta(), {".glb", ".obj"}, "m.urdf")
    with pytest.raises(CadImportError, match="perpendicular"):
        source_frame(ImportMeta(front_axis="+y"), {".glb"}, "m.urdf")  # glTF up +y, front +y
    with pytest.raises(CadImportError, match="perpendicular"):
        parse_meta({"up_axis": "+y", "front_axis": "-y"})
    with pytest.raises(CadImportError, match="unknown metadata keys"):
        parse_meta({"upaxis": "+y"})


def test_per_urdf_meta_overrides_the_folder(tmp_path: Path) -> None:
    (tmp_path / "meta.yaml").write_text("class: cabinet\nscale: 0.01\n")
    (tmp_path / "fridge.meta.yaml").write_text("class: fridge\nmodel_id: 'fridge #1'\n")
    fridge = load_model_meta(tmp_path / "fridge.urdf", tmp_path, shared_folder=True)
    assert (fridge.class_name, fridge.model_id, fridge.scale) == ("fridge", "fridge__1", 0.01)
    counter = load_model_meta(tmp_path / "counter.urdf", tmp_path, shared_folder=True)
    assert (counter.class_name, counter.model_id, counter.up_axis) == ("cabinet", None, None)
    (tmp_path / "meta.yaml").write_text("class: cabinet\nmodel_id: x\n")
    assert load_model_meta(tmp_path / "a.urdf", tmp_path, shared_folder=False).model_id == "x"
    with pytest.raises(CadImportError, match="ambiguous in a folder with several URDFs"):
        load_model_meta(tmp_path / "a.urdf", tmp_path, shared_folder=True)
    (tmp_path / "a.meta.yaml").write_text("- not a mapping\n")
    with pytest.raises(CadImportError, match=r"a\.meta\.yaml: metadata must be a mapping"):
        load_model_meta(tmp_path / "a.urdf", tmp_path, shared_folder=False)
