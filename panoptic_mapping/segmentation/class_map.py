"""Model output classes -> project classes (`config/classes.yaml`).

A model predicts its own label set (usually COCO); the project only knows its class table. Each
model class is resolved, in this order, through the model config's explicit `class_map`, an equal
project class name, then the class table's `coco` lists; a thing class that stays unresolved (a
COCO sink, bowl or laptop) becomes the model config's `fallback_class` (the generic `object`),
except placeholders (`N/A`, `__background__`), COCO stuff classes and the `ignore_classes` (people
and animals: they move), which are dropped.
"""

from __future__ import annotations

from collections.abc import Collection, Mapping, Sequence

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

#: Ids of the 91-entry COCO category list (torchvision detection models' `labels`: 0 is the
#: background, ten ids are unused) that the 80 thing classes take, in order.
COCO91_IDS: tuple[int, ...] = tuple(i for i in range(1, 91) if i not in (12, 26, 29, 30, 45, 66, 68, 69, 71, 83))
#: Placeholder of unused ids in category lists (torchvision's `N/A`).
PLACEHOLDER = "N/A"
#: The 91 COCO category names by id as torchvision's detection weights list them.
COCO91_NAMES: tuple[str, ...] = tuple(
    ["__background__"] + [COCO_THING_NAMES[COCO91_IDS.index(i)] if i in COCO91_IDS else PLACEHOLDER
                          for i in range(1, 91)]
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
    "coco91": COCO91_NAMES,
    "coco_panoptic": COCO_PANOPTIC_NAMES,
}
#: Model class names that are never a class (unused ids, the background channel).
PLACEHOLDER_NAMES = frozenset({PLACEHOLDER, "__background__", "background", "unlabeled", ""})
_STUFF_NAMES = frozenset(COCO_STUFF_NAMES)


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
        self,
        model_names: Sequence[str],
        table: ClassTable,
        overrides: Mapping[str, str] | None = None,
        fallback: str = "",
        ignore: Collection[str] = (),
    ) -> None:
        """fallback: project class of unresolved thing classes ("" or a class the table lacks: drop
        them); ignore: model classes dropped rather than sent to the fallback."""
        self.model_names = tuple(model_names)
        overrides = dict(overrides or {})
        unknown = sorted(set(overrides) - set(self.model_names))
        if unknown:
            raise SegmentationError(
                f"class_map names model classes {unknown} that the model does not have; "
                f"model classes: {list(self.model_names)}"
            )
        fallback_info = table.by_name(fallback) if fallback and fallback in table else None
        ignored = set(ignore)
        resolved: list[ClassInfo | None] = []
        #: Model classes that went to the fallback class (for logs).
        self.fallback_names: tuple[str, ...] = ()
        to_fallback = []
        for name in self.model_names:
            if name in overrides:
                target = overrides[name]
                resolved.append(table.by_name(target) if target else None)  # raises naming the valid classes
            elif name in table:
                resolved.append(table.by_name(name))
            elif (info := table.get_by_coco(name)) is not None:
                resolved.append(info)
            elif fallback_info is not None and not _never_fallback(name, ignored):
                resolved.append(fallback_info)
                to_fallback.append(name)
            else:
                resolved.append(None)
        self.fallback_names = tuple(to_fallback)
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

    def describe(self) -> str:
        """One line for logs: how many model classes map where."""
        n_fallback = len(self.fallback_names)
        line = f"{len(self)} model classes: {int(self.kept.sum()) - n_fallback} onto project classes"
        if n_fallback:
            target = self.classes[self.model_names.index(self.fallback_names[0])]
            line += f", {n_fallback} onto {target.name if target else ''!r}"
        return line + f", {int((~self.kept).sum())} dropped"

    def mapping(self) -> dict[str, str]:
        """model class name -> project class name, for the kept classes (for logs and docs)."""
        return {n: c.name for n, c in zip(self.model_names, self.classes, strict=True) if c is not None}


def _never_fallback(name: str, ignored: set[str]) -> bool:
    """Placeholders, COCO stuff (a `sky` or `road` region is no object) and ignored classes."""
    return name in PLACEHOLDER_NAMES or name.startswith("__") or name in _STUFF_NAMES or name in ignored
