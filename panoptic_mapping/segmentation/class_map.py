"""Model output classes -> project classes (`config/classes.yaml`).

A model predicts its own label set (usually COCO); the project only knows its class table. Each
model class is resolved, in this order, through the model config's explicit `class_map`, an equal
project class name, then the class table's `coco` lists; whatever stays unresolved is dropped
(a person or a pizza is not part of the scene model).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from panoptic_mapping.segmentation.types import SegmentationError
from recon_core.classes import UNKNOWN_CLASS_ID, ClassInfo, ClassTable

#: The 80 COCO thing classes in the order of their contiguous training ids (YOLO, torchvision, ...).
COCO_THING_NAMES: tuple[str, ...] = (
    "person", "bicycle", "car", "motorcycle", "airplane", "bus", "train", "truck", "boat", "traffic light",
    "fire hydrant", "stop sign", "parking meter", "bench", "bird", "cat", "dog", "horse", "sheep", "cow",
    "elephant", "bear", "zebra", "giraffe", "backpack", "umbrella", "handbag", "tie", "suitcase", "frisbee",
    "skis", "snowboard", "sports ball", "kite", "baseball bat", "baseball glove", "skateboard", "surfboard",
    "tennis racket", "bottle", "wine glass", "cup", "fork", "knife", "spoon", "bowl", "banana", "apple",
    "sandwich", "orange", "broccoli", "carrot", "hot dog", "pizza", "donut", "cake", "chair", "couch",
    "potted plant", "bed", "dining table", "toilet", "tv", "laptop", "mouse", "remote", "keyboard",
    "cell phone", "microwave", "oven", "toaster", "sink", "refrigerator", "book", "clock", "vase", "scissors",
    "teddy bear", "hair drier", "toothbrush",
)

#: The 53 (merged) stuff classes of COCO panoptic, after the things (Detectron2's contiguous order).
COCO_STUFF_NAMES: tuple[str, ...] = (
    "banner", "blanket", "bridge", "cardboard", "counter", "curtain", "door-stuff", "floor-wood", "flower",
    "fruit", "gravel", "house", "light", "mirror-stuff", "net", "pillow", "platform", "playingfield",
    "railroad", "river", "road", "roof", "sand", "sea", "shelf", "snow", "stairs", "tent", "towel",
    "wall-brick", "wall-stone", "wall-tile", "wall-wood", "water-other", "window-blind", "window-other",
    "tree-merged", "fence-merged", "ceiling-merged", "sky-other-merged", "cabinet-merged", "table-merged",
    "floor-other-merged", "pavement-merged", "mountain-merged", "grass-merged", "dirt-merged", "paper-merged",
    "food-other-merged", "building-other-merged", "rock-merged", "wall-other-merged", "rug-merged",
)

#: The 133 COCO panoptic classes (things then stuff).
COCO_PANOPTIC_NAMES: tuple[str, ...] = COCO_THING_NAMES + COCO_STUFF_NAMES

#: Names a model config may give instead of listing its classes.
CLASS_NAME_PRESETS: dict[str, tuple[str, ...]] = {
    "coco80": COCO_THING_NAMES,
    "coco_panoptic": COCO_PANOPTIC_NAMES,
}


def resolve_class_names(names: str | Sequence[str]) -> tuple[str, ...]:
    """A preset name (`coco80`, `coco_panoptic`) or an explicit list -> the model's class names."""
    if isinstance(names, str):
        try:
            return CLASS_NAME_PRESETS[names]
        except KeyError:
            raise SegmentationError(
                f"unknown class name preset {names!r}; valid presets: {sorted(CLASS_NAME_PRESETS)} "
                "(or give the model's class names as a list)"
            ) from None
    names = tuple(names)
    if not names:
        raise SegmentationError("the model's class name list is empty")
    return names


class ModelClassMap:
    """Model class index -> project `ClassInfo` (None: dropped), plus vectorised lookups."""

    def __init__(
        self, model_names: Sequence[str], table: ClassTable, overrides: Mapping[str, str] | None = None
    ) -> None:
        self.model_names = tuple(model_names)
        overrides = dict(overrides or {})
        unknown = sorted(set(overrides) - set(self.model_names))
        if unknown:
            raise SegmentationError(
                f"class_map names model classes {unknown} that the model does not have; "
                f"model classes: {list(self.model_names)}"
            )
        resolved: list[ClassInfo | None] = []
        for name in self.model_names:
            if name in overrides:
                target = overrides[name]
                resolved.append(table.by_name(target) if target else None)  # raises naming the valid classes
            elif name in table:
                resolved.append(table.by_name(name))
            else:
                resolved.append(table.get_by_coco(name))
        self.classes: tuple[ClassInfo | None, ...] = tuple(resolved)
        #: Project class id per model class (UNKNOWN_CLASS_ID where dropped).
        self.project_ids = np.array([c.id if c else UNKNOWN_CLASS_ID for c in resolved], np.int64)
        #: True where the model class maps onto a project class.
        self.kept = self.project_ids != UNKNOWN_CLASS_ID
        self._by_project_id = {c.id: c for c in resolved if c is not None}

    def __len__(self) -> int:
        return len(self.model_names)

    def __getitem__(self, index: int) -> ClassInfo | None:
        return self.classes[index]

    def project_class(self, class_id: int) -> ClassInfo:
        return self._by_project_id[class_id]

    def mapping(self) -> dict[str, str]:
        """model class name -> project class name, for the kept classes (for logs and docs)."""
        return {n: c.name for n, c in zip(self.model_names, self.classes, strict=True) if c is not None}
