"""What the sensor simulator renders: meshes in the map frame with a label and an appearance.

Kept separate from the scene generator (which decides *what* is in a room) so the renderer only
needs triangles, an integer id for the ground-truth label image and a recipe for colour.
"""

from __future__ import annotations

import colorsys
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
import trimesh

#: Procedural patterns the renderer knows. All are evaluated in world coordinates so a surface
#: shows the same texture from every view (features stay put, like real texture).
Pattern = Literal["plain", "noise", "stripes", "checker", "grain"]
PATTERNS: tuple[str, ...] = ("plain", "noise", "stripes", "checker", "grain")


@dataclass(frozen=True)
class Appearance:
    """Colour recipe of one item.

    base_color / secondary_color: linear RGB in [0, 1]; the pattern blends between them (a None
    secondary colour means a darker shade of the base colour). `scale_m` is the pattern period in
    metres; `contrast` in [0, 1] scales how strongly the pattern shows; `detail` adds fine
    multiplicative noise (grime, fabric) so even "plain" surfaces have trackable texture.
    `smooth_shading` interpolates vertex normals (curved objects such as spheres, cylinders) instead
    of using flat face normals (boxes, walls).
    """

    base_color: tuple[float, float, float] = (0.6, 0.6, 0.6)
    pattern: Pattern = "noise"
    secondary_color: tuple[float, float, float] | None = None
    scale_m: float = 0.25
    contrast: float = 0.5
    detail: float = 0.15
    smooth_shading: bool = False

    def __post_init__(self) -> None:
        if self.pattern not in PATTERNS:
            raise ValueError(f"unknown pattern {self.pattern!r}; choose one of {PATTERNS}")
        if not self.scale_m > 0:
            raise ValueError(f"pattern scale_m must be > 0, got {self.scale_m}")

    @property
    def secondary(self) -> tuple[float, float, float]:
        """The colour the pattern blends towards."""
        if self.secondary_color is not None:
            return self.secondary_color
        r, g, b = self.base_color
        return (0.55 * r, 0.55 * g, 0.55 * b)

    @classmethod
    def random(cls, rng: np.random.Generator, smooth_shading: bool = False) -> Appearance:
        """A plausible random appearance (saturated-ish colour, random pattern), for generators."""
        hue = float(rng.uniform())
        sat = float(rng.uniform(0.3, 0.8))
        val = float(rng.uniform(0.45, 0.9))
        base = colorsys.hsv_to_rgb(hue, sat, val)
        hue2 = (hue + float(rng.uniform(-0.08, 0.08))) % 1.0
        second = colorsys.hsv_to_rgb(hue2, min(1.0, sat * 1.1), val * float(rng.uniform(0.45, 0.75)))
        return cls(
            base_color=base,
            pattern=str(rng.choice(PATTERNS)),  # type: ignore[arg-type]
            secondary_color=second,
            scale_m=float(rng.uniform(0.05, 0.4)),
            contrast=float(rng.uniform(0.3, 0.8)),
            detail=float(rng.uniform(0.05, 0.25)),
            smooth_shading=smooth_shading,
        )


@dataclass
class RenderItem:
    """One ray-castable mesh (map frame) with its ground-truth label id and appearance.

    `label` is the value written into the label image (panoptic segment / instance id); 0 is
    reserved for "no surface". Several items may share a label (e.g. floor pieces).
    """

    mesh: trimesh.Trimesh
    label: int
    appearance: Appearance = field(default_factory=Appearance)
    name: str = ""

    def __post_init__(self) -> None:
        if int(self.label) <= 0:
            raise ValueError(f"item {self.name!r}: label must be a positive integer (0 means 'none')")
        if len(self.mesh.faces) == 0:
            raise ValueError(f"item {self.name!r} (label {self.label}) has an empty mesh")
        self.label = int(self.label)


def label_colors(labels: np.ndarray, saturation: float = 0.65, value: float = 0.9) -> np.ndarray:
    """(..., 3) uint8 RGB colours for integer labels; 0 -> black. Deterministic, well spread.

    Uses the golden-ratio hue sequence so consecutive ids get clearly different hues.
    """
    labels = np.asarray(labels, dtype=np.int64)
    hue = np.mod(labels * 0.618033988749895 + 0.1, 1.0)
    sat = np.where(labels % 3 == 1, saturation * 0.75, saturation)
    val = np.where(labels % 2 == 1, value, value * 0.8)
    # Vectorized HSV -> RGB.
    h6 = hue * 6.0
    i = np.floor(h6).astype(np.int64) % 6
    f = h6 - np.floor(h6)
    p = val * (1 - sat)
    q = val * (1 - sat * f)
    t = val * (1 - sat * (1 - f))
    table = np.stack(
        [
            np.stack([val, t, p], -1),
            np.stack([q, val, p], -1),
            np.stack([p, val, t], -1),
            np.stack([p, q, val], -1),
            np.stack([t, p, val], -1),
            np.stack([val, p, q], -1),
        ],
        axis=-2,
    )
    rgb = np.take_along_axis(table, i[..., None, None], axis=-2)[..., 0, :]
    rgb = np.where((labels == 0)[..., None], 0.0, rgb)
    return np.clip(np.round(rgb * 255.0), 0, 255).astype(np.uint8)
