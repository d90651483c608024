"""Tunables of the contact-graph builder (paper Sec. 2), one dataclass per step.

Defaults are the paper's values where it gives them (RANSAC 3 cm / 200 iterations / 10 %,
a_th = -0.9, b_th = 0.5, accept support at score > 0.2, REFERENCE.md) and measured choices
elsewhere; ``config/scene_graph.yaml`` holds the same keys (``load_scene_graph_config``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from recon_core.config import CONFIG_DIR, Settings, load_config, setting

#: Default YAML file of the contact-graph builder.
DEFAULT_CONFIG_FILE = CONFIG_DIR / "scene_graph.yaml"
#: Broad phases of the proximal-relation search: sort-and-prune, or the naive baseline.
BROADPHASES: tuple[str, ...] = ("sweep", "all_pairs")


@dataclass
class BoxConfig(Settings):
    """Gravity-aligned minimal box fitting (Sec. 2.2, Malandain and Boissonnat 2002)."""

    #: Percent of points trimmed on each side (xy in the rectangle frame, and z) against outliers;
    #: 0 keeps the exact extent (ground-truth meshes), ~0.5 suits noisy mapped meshes.
    trim_percent: float = setting(0.0, min=0.0, max=50.0, max_exclusive=True)
    #: Mesh surface samples added to the vertices before trimming (trimming needs an area-uniform
    #: cloud; a box mesh has 8 vertices). 0 uses the vertices only.
    surface_samples: int = 0


@dataclass
class PlaneConfig(Settings):
    """Surface planes: iterative RANSAC (paper) plus height groups of upward faces."""

    #: RANSAC inlier distance (m), iterations and stop fraction (paper: 3 cm, 200, 10 %).
    ransac_distance: float = 0.03
    ransac_iterations: int = 200
    ransac_min_fraction: float = 0.10
    #: Surface samples RANSAC runs on (the cost is samples x iterations per plane).
    ransac_samples: int = 1000
    #: Small objects: the RANSAC threshold shrinks to this share of the box diagonal (a cup would
    #: otherwise be one plane), as in the CAD feature extractor.
    ransac_relative_distance: float = 0.02
    max_planes: int = 12
    #: Horizontal support planes from upward faces grouped by height. RANSAC's 10 % rule drops
    #: small shelf levels and cabinet tops that carry objects; grouping keeps every level with at
    #: least ``min_support_area`` of upward surface.
    height_groups: bool = True
    #: Heights of upward faces within this distance (m) of a group's mode form one plane.
    height_tolerance: float = 0.015
    min_support_area: float = 0.004
    max_height_groups: int = 24
    #: Faces of a plane's support region: within this distance (m) of the plane ...
    region_distance: float = 0.02
    #: ... and with normal . plane normal above this cosine (mesh input only).
    region_normal_cos: float = 0.8
    seed: int = 0


@dataclass
class LayoutConfig(Settings):
    """Mapped layout entities -> layout nodes (``layout.py``): walls split into planar parts,
    stray faces dropped. Not in the paper, whose maps keep one entity per wall; a panoptic map
    has one entity per stuff class. Input that is already one element per entity (ground truth)
    passes unchanged."""

    enabled: bool = True
    #: Faces with |n_z| below this are vertical (wall candidates).
    vertical_max_nz: float = 0.3
    #: Faces within this angle (deg) of a wall's normal (either side) are parallel to it.
    parallel_deg: float = 15.0
    #: A layout element is at most this thick (m): faces this close to its plane belong to it
    #: (TSDF noise, both faces of a 10 cm ground-truth wall); farther ones are not part of it.
    thickness: float = 0.12
    #: A wall part needs this much area (m^2) and this length along the wall (m).
    min_area: float = 0.25
    min_length: float = 0.3
    #: Faces of one plane separated by more than this gap (m) along the wall are two walls.
    max_gap: float = 1.0
    max_parts: int = 16
    #: Split parts are numbered from max(part_id_base, largest entity id + 1) upwards.
    part_id_base: int = 1000


@dataclass
class GeometricLayoutConfig(Settings):
    """Layout from geometry (``geometric_layout.py``) for segmenters without layout classes (COCO
    detectors). NOT in the paper. Lengths in m, areas in m^2, in the gravity-aligned map frame."""

    enabled: bool = True
    #: Entities whose surface is searched for floor, walls and ceiling (the map's unclaimed surface).
    source_classes: list[str] = field(default_factory=lambda: ["unknown"])
    #: Faces within this of a horizontal group's height, or of a planar part, belong to it.
    plane_thickness: float = setting(0.04, min=0.0, min_exclusive=True)
    #: Layout elements: faces this far above/below the floor (ceiling) height join it (both faces of a slab).
    thickness: float = setting(0.08, min=0.0)
    #: The floor: the lowest horizontal group with at least this area and floor_min_share of the largest.
    floor_min_area: float = setting(1.0, min=0.0)
    floor_min_share: float = setting(0.2, min=0.0, max=1.0)
    #: The ceiling: the highest horizontal group this far above the floor, with this area and share of
    #: the floor's area.
    ceiling_min_height: float = setting(1.8, min=0.0)
    ceiling_min_area: float = setting(1.0, min=0.0)
    ceiling_min_floor_share: float = setting(0.25, min=0.0)
    #: A wall: a vertical planar part with this area, length and height ...
    wall_min_area: float = setting(0.75, min=0.0)
    wall_min_length: float = setting(0.5, min=0.0)
    wall_min_height: float = setting(1.0, min=0.0)
    #: ... or a wall seen only above the furniture in front of it (a kitchen's tiles above the
    #: counter): at least this area and height, its top at least wall_strip_min_top above the floor.
    wall_strip_min_area: float = setting(0.5, min=0.0)
    wall_strip_min_height: float = setting(0.3, min=0.0)
    wall_strip_min_top: float = setting(1.2, min=0.0)
    #: ... with at most this share of the map's surface area more than wall_outside_margin beyond it.
    wall_outside_share: float = setting(0.05, min=0.0, max=1.0)
    wall_outside_margin: float = setting(0.15, min=0.0)
    #: Things never claim layout: a horizontal/vertical planar part of a thing's mesh longer than
    #: size_factor x its class's max_size_m (config/classes.yaml), with at least give_up_min_area and
    #: give_up_min_share of its area, is given up to the layout.
    size_factor: float = setting(1.25, min=1.0)
    give_up_min_area: float = setting(0.3, min=0.0)
    give_up_min_share: float = setting(0.2, min=0.0, max=1.0)
    #: Once floor and walls are derived, a thing's faces within layout_band (m) of one of their planes,
    #: parallel to it (layout_band_deg) and within a wall's span (+ layout_band_margin) are layout: a
    #: detection mask bleeding onto the floor or the wall behind it (classes marked `flush` keep theirs).
    layout_band: float = setting(0.02, min=0.0)
    layout_band_deg: float = setting(15.0, min=0.0, max=90.0)
    layout_band_margin: float = setting(0.3, min=0.0)
    #: Coplanar faces farther apart than this (m) are two planar parts.
    plane_max_gap: float = setting(0.3, min=0.0)
    #: Ids of the derived floor, wall and ceiling entities: id_base, +1, +2 (must exceed every map id).
    id_base: int = setting(100000, min=1)


@dataclass
class FragmentConfig(Settings):
    """Stray fragments of object meshes (``fragments.py``); not in the paper (clean meshes assumed)."""

    enabled: bool = True
    #: Connected components whose bounds are at most this far apart (m) are one piece.
    max_gap: float = 0.05
    #: Pieces apart from the largest one are dropped below this share of the mesh area ...
    max_share: float = 0.05
    #: ... and, when more than far_gap (m) away from it, below far_share.
    far_gap: float = 0.15
    far_share: float = 0.25


@dataclass
class MergeConfig(Settings):
    """Over-segmented objects (``merge.py``): a same-class node mostly inside a larger one joins it.
    Not in the paper (its builder takes the map's instances as they are)."""

    enabled: bool = True
    #: Share of the smaller node's box volume inside the larger node's box.
    min_inside: float = 0.5
    #: Boxes are padded to this size per axis (m) first (a thin strip has no volume).
    min_extent: float = 0.02


@dataclass
class SupportConfig(Settings):
    """Support inference (Eqs. (1)-(3)) and its fallbacks (Sec. 2.2, Sec. 6.5)."""

    #: Eq. (1): a supporting plane needs n . g <= a_th with g = (0, 0, -1).
    a_th: float = setting(-0.9, min=-1.0, max=0.0)
    #: Eq. (2): contact-area ratio of a stable support.
    b_th: float = 0.5
    #: A support is accepted at score > accept_score (Eq. (3)), else the fallback applies.
    accept_score: float = 0.2
    #: Eq. (3) uses 1 - min(1, |D| / distance_scale); the paper's value is 1 m.
    distance_scale: float = setting(1.0, min=0.0, min_exclusive=True)
    #: Candidate planes may lie this far (m) above the child's box bottom (mesh noise, partial
    #: bottoms) and at most max_gap below it.
    above_tolerance: float = 0.04
    max_gap: float = 1.0
    #: Footprint grid for Eq. (2): cells per side (bounded) and the target cell size (m).
    grid_max_cells: int = 16
    grid_cell_size: float = 0.01
    #: A plane within this distance (m) of the child's bottom is in contact with it (Eq. (1) up to
    #: mesh noise); without one, invisible supporting planes are considered.
    contact_tolerance: float = 0.05
    #: Invisible supporting plane: the child's bottom lies between the candidate's box bottom +
    #: inferred_min_height and its top + invisible_max_gap (m), over >= b_th of its footprint.
    invisible_planes: bool = True
    invisible_max_gap: float = 0.08
    inferred_min_height: float = 0.05
    #: Eq. (2) on a mapped floor: the floor is never seen under the objects standing on it (a
    #: hole exactly under each footprint, contact ratio ~0). With this on, the floor's dominant
    #: supporting plane also covers the child's footprint cells that no other candidate's box
    #: footprint covers (nothing can stand between the floor and the child there); Eq. (3)'s
    #: distance term still applies. Not in the paper (its Eq. (2) assumes the floor was seen).
    floor_under_objects: bool = True
    #: Fallback: a child whose bottom is within this height (m) of the floor goes to the floor;
    #: otherwise the nearest wall within wall_distance (m) (an object hung on or leaning against
    #: a wall, Sec. 6.5), otherwise the floor (the root when there is no floor).
    floor_height: float = 0.15
    wall_distance: float = 0.15
    #: Classes of layout nodes.
    floor_classes: list[str] = field(default_factory=lambda: ["floor"])
    wall_classes: list[str] = field(default_factory=lambda: ["wall"])
    ceiling_classes: list[str] = field(default_factory=lambda: ["ceiling"])


@dataclass
class SurfaceSupportConfig(Settings):
    """Support patches from observed, undetected surfaces (``surfaces.py``): a movable thing left without
    a carrying plane gets a static slab under it when upward faces of the map's unlabelled surface or of
    its own mesh were seen near its bottom (a desk top the detector has no class for). NOT in the paper."""

    enabled: bool = True
    #: Class of the derived patch nodes (layout category: stage 4 exports them as static boxes).
    class_name: str = "surface"
    #: Upward faces within this (m) of the thing's bottom (its own: in its lowest quarter too) ...
    band: float = setting(0.03, min=0.0)
    #: ... under its footprint grown by ``margin`` (m; the patch covers that grown footprint) ...
    margin: float = setting(0.02, min=0.0)
    #: ... with at least min_area (m^2), or min_share of a small footprint, are an observed surface.
    min_area: float = setting(0.002, min=0.0)
    min_share: float = setting(0.1, min=0.0, max=1.0)
    #: Thickness (m) of the patch below the surface (stage 4's layout slabs are at least 5 cm).
    thickness: float = setting(0.05, min=0.0, min_exclusive=True)
    #: Only movable things (fixed ones are held by their joint).
    movable_only: bool = True
    #: Patch ids: id_base + the thing's id (must exceed every map id and the derived layout's).
    id_base: int = setting(200000, min=1)


@dataclass
class RefineConfig(Settings):
    """Box refinement (Fig. 3d): extend the box bottom down to the supporting plane."""

    enabled: bool = True
    #: Only move a bottom by at most this much (m): a far plane means a wrong support, not an
    #: occluded bottom.
    max_extension: float = 1.0
    #: Also lift a bottom that pokes below the plane (noise) up to it, so Eq. (1) holds exactly.
    lift_bottoms: bool = True


@dataclass
class ProximalConfig(Settings):
    """Proximal relations: pairs of non-supporting entities with overlapping boxes (Sec. 2.1)."""

    #: Boxes are inflated by this margin (m) before the overlap test (contacts that touch).
    margin: float = 0.02
    #: Broad phase: "sweep" (sort-and-prune on AABBs) or "all_pairs" (naive baseline).
    broadphase: str = setting("sweep", choices=BROADPHASES)
    #: Layout nodes take part (furniture against walls); off keeps object-object pairs only.
    include_layout: bool = True


@dataclass
class MatchConfig(Settings):
    """Matching predicted to ground-truth nodes for the metrics (Sec. 5.3)."""

    #: Objects: minimum 3D box IoU for a predicted node to correspond to a ground-truth node ...
    min_iou: float = 0.1
    #: ... or minimum share of the predicted box inside the ground-truth box (a partially seen cabinet).
    min_containment: float = 0.25
    #: Layout nodes match layout nodes of their class only, when at least this share of the
    #: predicted box lies inside the ground-truth box grown by layout_margin (m) per side.
    layout_min_containment: float = 0.5
    layout_margin: float = 0.1
    #: Added to the (1 - IoU) cost of a cross-class pair (allowed, counted as a substitution).
    class_mismatch_cost: float = 1.0
    #: Allow matches across classes at all (a mislabelled entity is a substitution).
    allow_class_mismatch: bool = True
    #: Boxes are padded to this size per axis (m) for matching: an observed wall is a flat face.
    min_extent: float = 0.05
    #: IoU threshold of the box mAP (Table 4).
    map_iou: float = 0.5
    #: "Seen-only" evaluation: a ground-truth entity counts as seen when the recording's camera
    #: saw at least this many of its pixels over all frames (scene.json ``visible_pixels``);
    #: unseen ones (and predictions matched to them) leave the comparison.
    seen_min_pixels: int = 10000


@dataclass
class SceneGraphConfig(Settings):
    """Everything the contact-graph builder reads; ``config/scene_graph.yaml`` has the same keys."""

    box: BoxConfig = field(default_factory=BoxConfig)
    planes: PlaneConfig = field(default_factory=PlaneConfig)
    layout: LayoutConfig = field(default_factory=LayoutConfig)
    geometric_layout: GeometricLayoutConfig = field(default_factory=GeometricLayoutConfig)
    fragments: FragmentConfig = field(default_factory=FragmentConfig)
    merge: MergeConfig = field(default_factory=MergeConfig)
    support: SupportConfig = field(default_factory=SupportConfig)
    surfaces: SurfaceSupportConfig = field(default_factory=SurfaceSupportConfig)
    refine: RefineConfig = field(default_factory=RefineConfig)
    proximal: ProximalConfig = field(default_factory=ProximalConfig)
    match: MatchConfig = field(default_factory=MatchConfig)
    #: Entities of these classes take no part in the graph (the mapper's "unknown" leftover
    #: surface is not an object; as a node it could even become a support parent).
    ignore_classes: list[str] = field(default_factory=lambda: ["unknown"])
    #: Class table file (empty: the repository's config/classes.yaml).
    class_table: str = ""
    #: Support-joint table file (empty: config/support_joints.yaml).
    support_joints: str = ""


def load_scene_graph_config(path: str | Path | None = None,
                            overrides: dict[str, object] | None = None) -> SceneGraphConfig:
    """Read the builder config (default ``config/scene_graph.yaml`` when it exists)."""
    if path is None and DEFAULT_CONFIG_FILE.is_file():
        path = DEFAULT_CONFIG_FILE
    return load_config(SceneGraphConfig, path, overrides)
