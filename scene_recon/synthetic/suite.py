"""The named benchmark suite every stage is evaluated on; generated on demand and cached.

Scenes are deterministic for their definition, so the cache key is the definition itself (plus
a format version): change a setting and the scene is regenerated, never silently reused.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
from dataclasses import asdict, dataclass, field
from pathlib import Path

from scene_recon.synthetic.generate import GenerateConfig, generate_recording, ground_truth_path
from scene_recon.synthetic.layout import LayoutConfig

SUITE_VERSION = 1


@dataclass(frozen=True)
class SuiteScene:
    name: str
    description: str
    seed: int
    objects: int
    frames: int
    layout: dict = field(default_factory=dict)  # LayoutConfig overrides


SUITE: dict[str, SuiteScene] = {s.name: s for s in [
    SuiteScene("bench-small", "a small furnished room, few objects (quick checks)", 101, 8, 150),
    SuiteScene("bench-kitchen", "kitchen: fridge, cabinets, oven, dishwasher, microwave, cups and bottles",
               202, 18, 300, {
                   "wall_classes": ["fridge", "cabinet", "oven", "dishwasher", "shelf"],
                   "wall_class_weights": [1.0, 2.0, 0.8, 0.8, 0.6],
                   "small_classes": ["cup", "bottle", "microwave", "box", "book"],
                   "small_class_weights": [2.0, 2.0, 0.8, 0.6, 0.4],
                   "ajar_probability": 0.5}),
    SuiteScene("bench-office", "office: desks, shelves, monitors, books, chairs", 303, 16, 300, {
        "wall_classes": ["desk", "shelf", "cabinet", "wardrobe", "sofa"],
        "wall_class_weights": [2.0, 1.5, 1.0, 0.4, 0.4],
        "small_classes": ["monitor", "book", "cup", "box", "bag"],
        "small_class_weights": [1.0, 2.0, 1.0, 0.6, 0.4]}),
    SuiteScene("bench-clutter", "a cluttered room: many small objects, stacks, ajar doors", 404, 30, 300, {
        "furniture_share": 0.3, "stack_probability": 0.6, "ajar_probability": 0.5}),
]}


def cache_root() -> Path:
    return Path(os.environ.get("SCENE_RECON_CACHE", Path.home() / ".cache" / "scene_recon")) / "suite"


def _key(scene: SuiteScene) -> str:
    blob = json.dumps({"v": SUITE_VERSION, **asdict(scene)}, sort_keys=True).encode()
    return hashlib.sha256(blob).hexdigest()[:12]


def scene_config(scene: SuiteScene) -> GenerateConfig:
    cfg = GenerateConfig(objects=scene.objects, frames=scene.frames, seed=scene.seed)
    cfg.layout = LayoutConfig(**{k: tuple(v) if isinstance(v, list) else v for k, v in scene.layout.items()})
    return cfg


def suite_scene(name: str, progress: bool = True, regenerate: bool = False) -> tuple[Path, Path]:
    """(bag, ground truth folder) of a suite scene, generating it on first use."""
    if name not in SUITE:
        raise KeyError(f"unknown suite scene {name!r}; known: {', '.join(SUITE)}")
    return scene_paths(SUITE[name], progress, regenerate)


def scene_paths(scene: SuiteScene, progress: bool = True, regenerate: bool = False) -> tuple[Path, Path]:
    """(bag, ground truth folder) of any scene definition (a suite scene or one of the robustness
    protocol's generated scenes), generated into the cache on first use."""
    name = scene.name
    bag = cache_root() / f"{name}-{_key(scene)}" / name
    gt = ground_truth_path(bag)
    done = gt / "generation.json"
    if regenerate or not done.is_file():
        shutil.rmtree(bag.parent, ignore_errors=True)
        generate_recording(bag, scene_config(scene), progress=progress)
    return bag, gt
