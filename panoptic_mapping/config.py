"""Configuration of the volumetric panoptic mapper (paper Sec. 3); mirrors `config/mapper.yaml`.

Defaults follow the paper's implementation (REFERENCE.md sec. 2) where it gives a value, scaled to
the processing resolution where the value is a pixel count.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from recon_core.config import Settings, setting

#: Mapper modes: the paper's method and the Voxblox++-style baseline of the ablation.
MODES: tuple[str, ...] = ("full", "baseline")


@dataclass
class DepthSegmentationConfig(Settings):
    """Convexity-based depth segmentation (Furrer et al. 2018, Tateno et al. 2015)."""

    #: Neighbour offsets (pixels, at processing resolution) compared for the edge tests.
    neighbour_offsets: list[int] = field(default_factory=lambda: [1, 2])
    #: Half window (pixels) of the box filter smoothing points before normal estimation.
    normal_smoothing: int = 2
    #: Half window (pixels) of the smoothing of points used by the edge tests (sensor noise).
    edge_smoothing: int = 1
    #: Pixel step of the finite differences used for normals.
    normal_step: int = 2
    #: Concave edge when n_i . n_j < this for a neighbour lying in front of the tangent plane.
    min_convexity: float = 0.97
    #: Depth discontinuity when |(p_j - p_i) . n_i| > this * depth_i.
    max_discontinuity_ratio: float = 0.01
    #: Plus an absolute floor (m) on the discontinuity test, against sensor quantization.
    min_discontinuity_m: float = 0.02
    #: Segments smaller than this many pixels (at full 640x480 resolution) are dropped.
    min_segment_pixels: int = 200


@dataclass
class FusionConfig(Settings):
    """Per-frame fusion of panoptic masks and geometric segments (Sec. 3.1)."""

    #: Split a geometric segment to keep a panoptic mask it fully contains: the mask covers more
    #: than `split_mask_coverage` of itself inside the segment and less than `split_segment_share`
    #: of the segment (REFERENCE.md: 0.9 / 0.5).
    split: bool = True
    split_mask_coverage: float = 0.9
    split_segment_share: float = 0.5
    #: Our extension: the mask may be spread over several segments it is a minority of, as long as
    #: together they contain it (> split_mask_coverage); false = the paper's single-segment rule.
    split_across_segments: bool = True
    #: Our extension (full mode): a mask lying mostly on depth-edge pixels (small objects, which the
    #: convexity segmentation shreds into edges) becomes a segment of its own.
    rescue_edge_masks: bool = True
    #: A geometric segment takes the label of the mask covering most of it if that mask covers at
    #: least this share of it; otherwise it is background (REFERENCE.md: 0.2).
    min_label_share: float = 0.2
    #: Euclidean clustering of one instance's segments (Sec. 3.1): segments closer than this (m)
    #: belong together; only the largest cluster keeps the instance label.
    cluster: bool = True
    cluster_distance_m: float = 0.05
    #: Points subsampled per segment for the pairwise distance test (speed; exact enough).
    cluster_max_points: int = 400
    #: Our extension (full mode): depth-edge pixels inside a mask join the mask's largest segment,
    #: unless farther than the margin (m) outside that segment's depth range.
    absorb_edge_pixels: bool = True
    absorb_depth_margin_m: float = 0.15
    #: Our extension (full mode): a stuff mask's depth-edge pixels (rescued or absorbed above) that lie
    #: more than `stuff_front_ratio` x depth (at least `stuff_front_min_m`) in front of the plane fitted
    #: to that mask's pixels within `stuff_front_window_px` stay unlabelled: a wall mask bleeding over a
    #: cup in front of the wall gives the cup's pixels no wall vote (0 ratio: off).
    stuff_front_ratio: float = 0.03
    stuff_front_min_m: float = 0.05
    stuff_front_window_px: int = 61
    #: Segments with fewer points (at full 640x480 resolution) are not integrated with a label
    #: (the paper used 800; 300 keeps cups and bottles a few metres away).
    min_segment_points: int = 300


@dataclass
class AssociationConfig(Settings):
    """Data association of frame segments to global segments (Sec. 3.2)."""

    #: A frame segment joins the global segment with the most overlapping voxels if that overlap is
    #: at least this share of the segment's points found in the map.
    min_overlap_share: float = 0.2
    #: ... and at least this many points.
    min_overlap_points: int = 20
    #: Use every n-th pixel (in both directions) for the overlap counts and the label votes: a 2 cm
    #: voxel spans several pixels, so a stride of 2 loses nothing measurable and saves 4x the work.
    pixel_stride: int = 2
    #: Two global segments a frame segment overlaps (each above the share) in this many frames merge.
    merge_min_frames: int = 3
    merge_overlap_share: float = 0.2


@dataclass
class RegularizationConfig(Settings):
    """Map regularization (Sec. 3.3)."""

    #: Run segment / instance merging every this many integrated frames (0: only at extraction).
    every_n_frames: int = 10
    #: Instance merging Eq. (5): shared votes >= m_th * all votes, and > min_shared_votes.
    instance_merge_ratio: float = 0.5
    instance_merge_min_votes: int = 10


@dataclass
class TSDFConfig(Settings):
    voxel_size_m: float = 0.02
    truncation_voxels: float = 4.0
    block_resolution: int = 8
    initial_block_count: int = 20000
    min_depth_m: float = 0.1
    max_depth_m: float = 4.0
    max_weight: float = 100.0
    #: Voxel weight needed for a surface to be meshed.
    mesh_weight_threshold: float = 2.0


@dataclass
class FineSurfaceConfig(Settings):
    """A finer TSDF for small things (`panoptic_mapping.fine_surface`): books, cups, bottles and monitor
    stands are mapped at `voxel_size_m` beside the room's `tsdf.voxel_size_m`. On by default since
    2026-11-29, at 5 mm and together with `free_space`: over the robustness protocol's 24 scene-draws mapped
    CAD pose success 57.1 -> 64.7 %, 3D PQ 89.7 -> 87.8 (docs/STAGE2_MAPPING.md); `enabled: false` is the
    paper's single-resolution map."""

    enabled: bool = True
    #: 5 mm: a 16 mm book's thickness and a cup's rim need it (1 cm left most books 1.5-2x too thick).
    voxel_size_m: float = setting(0.005, min=0.002)
    truncation_voxels: float = setting(4.0, min=1.0)
    block_resolution: int = 8
    #: Rigid thing classes whose class-table `max_size_m` is at most this get the fine surface (0.8:
    #: monitor, bag, box, bottle, book, cup; not furniture, whose 2 cm surface is fine for its size, nor
    #: articulated classes, whose parts are fitted on the room's surface).
    max_class_size_m: float = setting(0.8, min=0.0)
    #: Pixels the small things' silhouettes grow by: their edges are what the coarse map blurs.
    dilate_px: int = setting(4, min=0)
    #: Small things' own labels vote only this many pixels inside their silhouette (edge pixels mix
    #: depths). 0: every pixel. 2 thinned a bottle's fringe on bench-kitchen but took a monitor's base plate
    #: (a band a few pixels high) away on bench-office (draw 0: mapped pose success 0.9 -> 0.7).
    label_erode_px: int = setting(0, min=0)
    #: A fine vertex belongs to the entity of the nearest coarse vertex within this many coarse voxels.
    assign_radius_voxels: float = setting(1.5, min=0.1)
    #: Unlabelled fine vertices join the entity of their nearest coarse vertex (its fringe), as the coarse
    #: fill does. Off: they lie on the support around a small thing (the grown ring), and 3D PQ gave the
    #: table's points near a cup to the cup (bench-kitchen cup PQ 26 -> 0 with it on).
    fill: bool = False
    #: An entity takes the fine surface when it comes within `assign_radius_voxels` of at least this
    #: share of its voted coarse vertices.
    min_coverage: float = setting(0.5, min=0.0, max=1.0)


@dataclass
class StaticConfig(Settings):
    """A camera standing still: a frame that moved less than this since the last integrated frame sees
    the same surfaces from the same place and adds nothing to the map, so it is skipped whole
    (segmentation included), except one every `max_interval_s`: a still camera keeps seeing a scene
    that changes (someone moves the cup)."""

    enabled: bool = True
    max_translation_m: float = setting(0.005, min=0.0)
    max_rotation_deg: float = setting(0.5, min=0.0)
    max_interval_s: float = setting(1.0, min=0.0)
    #: Frames from one still viewpoint integrated before the skipping starts: a surface is meshed once
    #: its voxels have `tsdf.mesh_weight_threshold` (2) observations, so a still camera's first views
    #: still count (a short recording from a tripod is not left empty).
    min_views: int = setting(3, min=1)


@dataclass
class KeyframeConfig(Settings):
    """Segment only keyframes; other frames integrate geometry and reuse the map's labels."""

    enabled: bool = True
    min_translation_m: float = 0.15
    min_rotation_deg: float = 10.0
    max_interval_s: float = 1.0
    #: Every n-th non-keyframe also segments depth and propagates the map's labels into unknown
    #: voxels (costs ~4x a geometry-only frame); the others integrate geometry only. 1 = all, 0 = none:
    #: the default since issue 26 (over the robustness protocol's 16 scene-draws, 3 against 0: PQ
    #: 88.10 / 88.14, box mAP 72.2 / 72.9 %, pose success 55.7 / 56.9 %, mapping 83 / 60 ms a frame;
    #: the keyframes' labels already cover what the camera sees, the cadence only cost time).
    label_every_n_frames: int = 0


@dataclass
class ExtractionConfig(Settings):
    """Entity extraction (Sec. 3.4)."""

    #: Birth of a thing entity: its instance must have been chosen in at least this many segmented
    #: frames. One frame is what a network's flicker fakes (a spurious blob, a split-off piece of a
    #: mask); on 6 maps of the robustness protocol's scenes (4 scenes, draws 0-1) every false thing
    #: entity had 1 frame and every true one >= 2 (docs/STAGE2_MAPPING.md, "Instances that survive
    #: noise"). 1 is the paper's rule (every detection is born). While no instance has been segmented
    #: more often than once, one frame is enough.
    min_instance_frames: int = setting(2, min=1, doc="segmented frames a thing instance needs to become an entity")
    #: A thing fragment below `min_instance_frames` whose surface touches (within 1.5 voxels) an entity
    #: of its own class joins that entity (a split-off part of a cabinet); other fragments are dropped
    #: and their surface goes to the fill below (or stays unknown). False: fragments are just dropped.
    merge_fragments: bool = setting(True, doc="fragments below min_instance_frames join a touching entity "
                                    "of their class")
    #: A mesh face belongs to the entity of at least two of its three vertices (false: only to the entity
    #: of all three; faces between entities went to `unknown`, a one-voxel band around every entity, which
    #: is most of a small thing's surface at 2 cm voxels). docs/STAGE2_MAPPING.md, "Small things far away".
    face_majority: bool = setting(True, doc="a mesh face belongs to the entity of two of its three vertices")
    #: Entities with fewer mesh vertices are dropped.
    min_entity_voxels: int = 50
    #: A thing entity whose mesh area is under this share of the most surface one segmented frame showed
    #: of its instance (pixels x (z / f)^2) is dropped: the map's votes gave what its frames saw to other
    #: entities, and what it keeps is a shred (a wrong class flickered onto part of an object in two frames
    #: on bench-office draw 1: 64 vertices of a `sofa`; docs/STAGE2_MAPPING.md). 0 disables (the paper).
    min_observed_share: float = setting(0.25, min=0.0, max=1.0, doc="share of the surface one frame showed of "
                                        "a thing instance its entity must own in the map (0: any)")
    #: Also output the reconstructed surface no entity claims, as entity 0 of class -1 ("unknown"):
    #: evaluation must know that geometry was observed there even if it was not recognised.
    include_unknown: bool = True
    #: A thing entity with at least this share of its vertices within 1.5 voxels of a larger entity of
    #: its own class joins it (one object whose instance tracking split: a table's legs, half a chair).
    #: On 6 maps of the protocol's scenes (kitchen draws 0-1, office, clutter, gen-8686, gen-7373): such
    #: splits touched along 10-20 % of the smaller part, separate objects of one class along < 2 %.
    #: 0 disables (the paper's extraction).
    merge_touching_share: float = setting(0.05, min=0.0, max=1.0, doc="share of a thing's vertices touching a "
                                          "larger same-class entity that merges it into that entity (0: never)")
    #: A thing entity's surface pieces (vertices linked within this distance, m) that lie beside its largest
    #: piece, outside that piece's footprint from above grown by the same distance, and hold less than half
    #: of its surface leave it: a mask that spilt over a depth edge onto the wall or table behind (a
    #: monitor took 264 vertices 70 cm behind it on gen-4242). Legs and shelves below a top stay (inside the
    #: footprint). 0 disables (the paper's extraction).
    detached_gap_m: float = setting(0.2, min=0.0, doc="link distance of a thing's surface pieces; pieces beside "
                                    "its largest one leave it (0: never)")
    #: Reconstructed vertices no entity claims join the nearest claimed vertex's entity within this
    #: radius (m): the unvoted fringe along depth edges. 0 disables.
    fill_radius_m: float = 0.08
    #: Ignore classes with this id (the "unknown/background" class).
    background_class_id: int = -1


@dataclass
class CheckpointConfig(Settings):
    """Periodic checkpoints of the map (`scene-recon map`: <out>/checkpoints; the node: <data_root>/checkpoints).

    A checkpoint is written when either trigger fires (and on SIGINT/SIGTERM); each is a complete
    generation folder renamed into place, so a crash mid-write keeps the previous one.
    """

    enabled: bool = setting(True, doc="write periodic checkpoints and one on SIGINT/SIGTERM")
    every_n_frames: int = setting(100, min=0, doc="checkpoint after this many integrated frames (0: never by count)")
    every_s: float = setting(60.0, min=0.0, doc="checkpoint after this many seconds of mapping (0: never by time)")
    keep: int = setting(2, min=1, doc="checkpoint generations kept: the newest and older ones to fall back on")


@dataclass
class FreeSpaceConfig(Settings):
    """Free-space evidence (`panoptic_mapping.free_space`): a thing's surface that the label frames looked
    through or measured in fewer than `min_seen` of them (the TSDF's truncation band closing a face seen
    from one side) stays the entity's but as fringe (`Entity.core_vertices`), so model fitting reads only
    what was measured. On by default since 2026-11-29, with the 5 mm `fine_surface`: alone it was +4.6
    points of mapped pose success but moved real-data gate decisions the wrong way; with the fine surface
    both real recordings meet issue 22's criteria (docs/STAGE2_MAPPING.md, docs/REAL_DATA.md).
    `enabled: false` is the paper's extraction."""

    enabled: bool = setting(True, doc="thing surface the label frames never measured is fringe, not core")
    #: Keep every n-th pixel of a label frame's depth (each direction).
    downsample: int = setting(2, min=1, doc="pixel stride of the stored label-frame depth")
    #: A stored pixel holds the nearest reading within this many full-resolution pixels: a silhouette's
    #: edge (and the pose's error there) never reads as looked through.
    edge_margin_px: int = setting(2, min=0, doc="nearest reading within this many pixels (silhouette margin)")
    #: At most this many views are kept; beyond, every other one is dropped (spread over the recording).
    max_views: int = setting(96, min=1, doc="label-frame views kept for the free-space test")
    #: A reading within tolerance_voxels * voxel + tolerance_per_m * depth of a vertex saw it; farther
    #: readings looked through it.
    tolerance_voxels: float = setting(1.0, min=0.0, doc="seen/looked-through tolerance, in room voxels")
    #: The fixed part of that tolerance for the fine surface of small things (`fine_surface`), in place of
    #: the room's voxels: its 5 mm grid closes a face seen from one side 2 cm (the truncation band) behind
    #: it, and the room's 2 cm took that for measured surface. 1 cm: in the robustness protocol (8 scenes x
    #: 3 draws) 5 mm and 1 cm both placed more CAD models right (mapped pose success 69.3 ± 20.8 -> 71.4 ±
    #: 22.4 / 70.4 ± 22.0 %, worst draw 20.0 in all three), but at 5 mm the real kitchen's cup (stride 1) lost
    #: the surface pose and depth error put beyond it and fell to its scan (docs/STAGE2_MAPPING.md).
    fine_tolerance_m: float = setting(0.01, min=0.0, doc="fixed part of the seen tolerance for the fine surface (m)")
    #: A fine-surface vertex measured by fewer than this share of the median number of views that measured
    #: its thing's fine surface is fringe too: the shadow of the truncation band past a far edge no camera
    #: saw (a lying book's top closed 1.6-4.5 cm past its edge, measured by 1-3 views where the rest of it
    #: was by 14). Protocol: mapped pose success 70.4 ± 22.0 % (worst 20.0) -> 72.3 ± 19.7 % (worst 25.0);
    #: shares 0.15 and 0.35 gained less on saved maps. 0 disables (docs/STAGE2_MAPPING.md).
    fine_min_seen_share: float = setting(0.25, min=0.0, max=1.0,
                                         doc="fine vertices measured by fewer than this share of their thing's "
                                         "median views are fringe (0: off)")
    tolerance_per_m: float = setting(0.01, min=0.0, doc="seen/looked-through tolerance added per metre of depth")
    #: A vertex is fringe when at least this many views looked through it ...
    min_through: int = setting(2, min=1, doc="views that must look through a vertex to drop it")
    #: ... and more than `through_ratio` times as many as saw it.
    through_ratio: float = setting(1.0, min=0.0, doc="looked-through views per seeing view needed to drop a vertex")
    #: A thing vertex that fewer views saw (measured within the tolerance) is fringe too: the surface the
    #: TSDF closes behind a face seen from one side, which no frame measured. 2, as a thing's birth needs two
    #: segmented frames (`extraction.min_instance_frames`); 0: only looked-through vertices.
    min_seen: int = setting(2, min=0, doc="views that must have measured a thing vertex for it to stay core "
                            "(0: any)")
    #: Only thing classes whose class-table `max_size_m` is at most this (0: every thing class). The
    #: truncation band's shadow is a few centimetres: twice a book's thickness, a few per cent of a cabinet's.
    max_class_size_m: float = setting(0.0, min=0.0, doc="only thing classes up to this size (m; 0: all)")
    #: Each thing entity carries the grid of the space around it that the views observed
    #: (`recon_core.geometry.observed_space`): stage 4 does not count model surface in unknown space as
    #: missing and lets an observed box grow into it (an unseen far half is unknown, not absent). Off by
    #: default: over the robustness protocol it placed more CAD models and more of them right, but a
    #: smaller share of the placed ones (docs/STAGE4_CAD.md, "Observed and unknown space").
    observed_grid: bool = setting(False, doc="attach the observed/unknown grid around each thing entity")
    #: The grid reaches this share of the entity's largest extent beyond its box on every side ...
    observed_grid_margin: float = setting(0.6, min=0.0, doc="grid margin, as a share of the entity's largest extent")
    #: ... at least `observed_grid_min_margin_m` and at most `observed_grid_max_margin_m`.
    observed_grid_min_margin_m: float = setting(0.1, min=0.0, doc="smallest grid margin (m)")
    observed_grid_max_margin_m: float = setting(1.0, min=0.0, doc="largest grid margin (m)")
    #: Cells along the grid's longest side (cubic cells: 2.4 m -> 10 cm, a cup's 0.3 m -> 12 mm).
    observed_grid_cells: int = setting(24, min=2, doc="cells along the observed grid's longest side")


@dataclass
class MapperConfig(Settings):
    #: "full" = the paper's method; "baseline" = Voxblox++-style fusion (greedy labels, separate
    #: semantic and instance tracking, no split, no clustering) for the ablation.
    mode: str = setting("full", choices=MODES)
    #: Process images downscaled by this integer factor (2: 640x480 -> 320x240; ~2x faster, small
    #: objects suffer: clean-oracle PQ 88.4 vs 92.0 on bench-kitchen).
    downsample: int = setting(1, min=1)
    depth_segmentation: DepthSegmentationConfig = field(default_factory=DepthSegmentationConfig)
    fusion: FusionConfig = field(default_factory=FusionConfig)
    association: AssociationConfig = field(default_factory=AssociationConfig)
    regularization: RegularizationConfig = field(default_factory=RegularizationConfig)
    tsdf: TSDFConfig = field(default_factory=TSDFConfig)
    fine_surface: FineSurfaceConfig = field(default_factory=FineSurfaceConfig)
    free_space: FreeSpaceConfig = field(default_factory=FreeSpaceConfig)
    keyframes: KeyframeConfig = field(default_factory=KeyframeConfig)
    static: StaticConfig = field(default_factory=StaticConfig)
    extraction: ExtractionConfig = field(default_factory=ExtractionConfig)
    checkpoint: CheckpointConfig = field(default_factory=CheckpointConfig)
