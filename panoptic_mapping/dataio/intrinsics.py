"""Camera intrinsics from files and options: 3x3 / 4x4 matrix text files, `camera.yaml`, `fx,fy,cx,cy`.

Files found beside frame folders, in order of precedence:

* ``camera.yaml``            ``fx, fy, cx, cy`` (optionally ``depth_scale``) - this project's own;
* ``camera-intrinsics.txt``  3DMatch / 7-Scenes-style exports: a 3x3 matrix;
* ``intrinsics.txt``         a 3x3 or 4x4 matrix (ScanNet-style).

A matrix file holds whitespace-separated numbers: 9 (3x3 K), 16 (4x4 with K in the top-left
corner) or 4 (``fx fy cx cy``). Skew is ignored (pinhole model).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import yaml

from recon_core.errors import ConfigError, DatasetError

#: Matrix files looked for beside frames, in order (camera.yaml is read separately).
MATRIX_FILES = ("camera-intrinsics.txt", "intrinsics.txt")

Intrinsics4 = tuple[float, float, float, float]


def _check(values: Intrinsics4, where: str) -> Intrinsics4:
    fx, fy = values[0], values[1]
    if not np.all(np.isfinite(values)) or fx <= 0 or fy <= 0:
        raise DatasetError(f"{where}: focal lengths must be finite and > 0, got fx={fx}, fy={fy}")
    return values


def read_matrix_intrinsics(path: str | Path) -> Intrinsics4:
    """(fx, fy, cx, cy) from a 3x3 / 4x4 matrix text file (or one with the 4 numbers)."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise DatasetError(f"cannot read intrinsics file {path}: {exc}") from exc
    try:
        vals = np.array([float(v) for v in text.replace(",", " ").split()], dtype=np.float64)
    except ValueError as exc:
        raise DatasetError(f"{path}: intrinsics file must hold numbers only (a 3x3 or 4x4 matrix): {exc}") from exc
    if vals.size == 4:
        return _check((float(vals[0]), float(vals[1]), float(vals[2]), float(vals[3])), str(path))
    if vals.size not in (9, 16):
        raise DatasetError(f"{path}: expected a 3x3 or 4x4 matrix (9 or 16 numbers) or fx fy cx cy, "
                           f"found {vals.size} numbers")
    n = 3 if vals.size == 9 else 4
    k = vals.reshape(n, n)
    if abs(k[2, 0]) > 1e-9 or abs(k[2, 1]) > 1e-9 or abs(k[2, 2] - 1.0) > 1e-6:
        raise DatasetError(f"{path}: not a camera matrix (third row must be 0 0 1), got {k[2, :3].tolist()}")
    return _check((float(k[0, 0]), float(k[1, 1]), float(k[0, 2]), float(k[1, 2])), str(path))


def read_yaml_intrinsics(path: str | Path) -> tuple[Intrinsics4, dict]:
    """(fx, fy, cx, cy) and the whole mapping of a `camera.yaml`-style file."""
    path = Path(path)
    data = yaml.safe_load(path.read_text(encoding="utf-8")) or {}
    if not isinstance(data, dict):
        raise DatasetError(f"{path}: expected a mapping with fx, fy, cx, cy")
    try:
        k = (float(data["fx"]), float(data["fy"]), float(data["cx"]), float(data["cy"]))
    except KeyError as exc:
        raise DatasetError(f"{path} lacks {exc}") from exc
    except (TypeError, ValueError) as exc:
        raise DatasetError(f"{path}: fx, fy, cx, cy must be numbers: {exc}") from exc
    return _check(k, str(path)), data


def read_intrinsics_file(path: str | Path) -> Intrinsics4:
    """Any supported intrinsics file: YAML (`.yaml`/`.yml`) or a matrix text file."""
    path = Path(path)
    if not path.is_file():
        raise DatasetError(f"intrinsics file {path} does not exist")
    if path.suffix.lower() in (".yaml", ".yml"):
        return read_yaml_intrinsics(path)[0]
    return read_matrix_intrinsics(path)


def find_matrix_file(folders: list[Path]) -> Path | None:
    """The first `camera-intrinsics.txt` / `intrinsics.txt` in `folders` (searched in order)."""
    for folder in folders:
        for name in MATRIX_FILES:
            if (folder / name).is_file():
                return folder / name
    return None


def parse_intrinsics_option(values: list[str] | str) -> tuple[list[float], str]:
    """`--intrinsics` value(s) -> ([fx, fy, cx, cy], "") or ([], file path).

    Accepts four numbers (``500 500 319.5 239.5``), one comma-separated string
    (``500,500,319.5,239.5``) or the path of an intrinsics file (matrix text or YAML).
    """
    if isinstance(values, str):
        values = [values]
    tokens = [t for v in values for t in v.replace(",", " ").split()]
    try:
        nums = [float(t) for t in tokens]
    except ValueError:
        nums = []
    if nums and len(nums) == len(tokens):
        if len(nums) != 4:
            raise ConfigError(f"--intrinsics needs 4 numbers fx,fy,cx,cy (or a file), got {len(nums)}")
        try:
            _check((nums[0], nums[1], nums[2], nums[3]), "--intrinsics")
        except DatasetError as exc:
            raise ConfigError(str(exc)) from exc
        return nums, ""
    if len(values) == 1:
        path = Path(values[0])
        if not path.is_file():
            raise ConfigError(f"--intrinsics {values[0]!r}: neither fx,fy,cx,cy nor an existing file")
        read_intrinsics_file(path)  # fail early on a bad file
        return [], str(path)
    raise ConfigError(f"--intrinsics takes fx,fy,cx,cy or one file, got {' '.join(values)!r}")
