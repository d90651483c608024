"""All tunables of CAD replacement (paper Sec. 4.2-4.3) in one dataclass, with the paper's values.

``method="paper"`` reproduces the paper's anchors (24 orientations for every candidate, L1 box
term + Hungarian plane term, one dense LM per candidate from its box start, selection by the
one-sided AE of Sec. 4.3); ``method="ours"`` restricts orientations by gravity, adds a front term,
fits coarse-to-fine on subsamples with a robust residual, estimates joint values and selects by a
two-sided AE. Both read their parameters from here so a benchmark can compare them fairly.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

Method = Literal["ours", "paper"]


@dataclass(frozen=True)
class CadReplacementConfig:
    """Parameters of matching, alignment, articulation and selection (lengths in metres)."""

    #: "ours" (gravity-restricted, coarse-to-fine, two-sided AE) or "paper" (Sec. 4.2-4.3 anchors).
    method: Method = "ours"

    # ------------------------------------------------------------------ matching (Sec. 4.2)
    #: Ours: extra box frames aligned with the largest vertical observed planes (robust to a box
    #: tilted by an open door); the paper uses the observed box only.
    extra_frames: int = 2
    #: Ours: read the map's grid of observed and unknown space around an entity where it carries one
    #: (``Entity.observed_space``; the mapper's ``free_space.observed_grid``, off by default; issue 22
    #: item 4): model surface in unknown space is not missing data, and a box side facing unknown
    #: space may grow towards the model's own proportions (a half-seen table is not its seen half).
    observed_space: bool = True
    #: Ours: elevation (deg) of the line of sight along which the loads an object carries hide its top
    #: (``ObjectObservation.hidden_by_loads``): such model surface is unseen, not missing, in the fits
    #: and the AE. 0 turns it off (the paper has no such term).
    load_shadow_elevation_deg: float = 30.0
    #: Ours, with an observed-space grid: the most (m) a CAD sample in unknown space adds to the
    #: CAD -> observation half of the AE (its distance to the observed surface, capped).
    unknown_surface_m: float = 0.01
    #: Oriented candidates kept after matching. REFERENCE.md: the paper's code keeps k = 20 (the
    #: IJCV text says 10).
    top_k: int = 20
    #: Eq. (7) weights: omega_1 (box size, Eq. 8), omega_2 (planes, Eq. 9), omega_3 (bias, Eq. 10);
    #: the paper sets 1.0, 1.0 and 0.2.
    w_size: float = 1.0
    w_plane: float = 1.0
    w_bias: float = 0.2
    #: Ours: weight of the front term (model front vs ``front_hint``; 0 aligned .. w_front opposite).
    w_front: float = 0.5
    #: Ours: matching penalty of a model from an interchangeable (confusable) class rather than the
    #: observed one: the detector's label is trusted unless the geometry clearly says otherwise.
    w_class: float = 0.1
    #: Ours: Eq. (9) cost of an observed plane left without a partner (|Pi_x| > |Pi_y|). Kept small:
    #: CAD feature lists hold only the dominant planes (a table lists its top), so a missing partner
    #: is weak evidence. The paper's bijection matches the smaller set only (cost 0 here).
    plane_unmatched_cost: float = 0.3
    #: RANSAC on the observation (Sec. 4.1 uses 3 cm, 200 iterations, 10 % stop fraction); ``None``:
    #: min(3 cm, 2 % of the box diagonal) as for CAD models, so small objects get planes too.
    plane_distance: float | None = None
    plane_iterations: int = 200
    plane_min_fraction: float = 0.10
    #: Points given to RANSAC (a random subsample; planes need far fewer than alignment).
    plane_samples: int = 1500

    # ------------------------------------------------------------------ alignment (Sec. 4.3)
    #: Ours, coarse stage: every top-k candidate is scored at its box start on ``screen_points``;
    #: the best ``screen_fits`` get a short LM of ``screen_max_nfev`` evaluations.
    screen_points: int = 150
    screen_fits: int = 6
    screen_max_nfev: int = 6
    #: Ours: candidates kept after screening for the full fit (with articulation).
    screen_keep: int = 3
    #: Ours: points (subsample) and CAD samples in the full LM fit, and its LM evaluations.
    align_points: int = 500
    align_model_samples: int = 200
    align_max_nfev: int = 30
    #: Relative cost decrease below which an LM fit stops before its evaluation budget (MINPACK
    #: ``ftol``; the same for both methods). At 1e-4 the suite's poses, AE, articulation and GED are
    #: those of scipy's 1e-8 while the fits take ~20 % fewer evaluations (bench_cad.py, both values).
    fit_ftol: float = 1e-4
    #: Paper: points used by its dense LM (all of them, capped for memory).
    paper_max_points: int = 4000
    #: Robust scale tau (m) of the soft-L1 residual of ours: points farther than ~tau from the CAD
    #: surface (an open door fitted with a closed model, clutter) stop pulling the fit.
    robust_scale: float = 0.02
    #: Ours: price (m) of explaining an observed point by a moving part at some joint value other
    #: than closed (articulation envelope, ``alignment.envelope_mesh``): bodies fit through open
    #: doors and pulled-out drawers, yet a point the body itself can explain prefers the body.
    envelope_margin: float = 0.02
    #: Ours: weight (m per unit log-anisotropy, per point) pulling per-axis scales towards a common
    #: one: CAD proportions are a prior where the data says little (unseen back of an object).
    anisotropy_weight: float = 0.002
    #: Ours: weight (per point, dimensionless) of Eq. (13)'s height term: model height = observed
    #: height from the support to the box top (the top of a tall object is often unseen, so the
    #: points alone hardly fix the vertical scale).
    height_weight: float = 0.3
    #: Ours: weight (per point) tying the two horizontal scales of a round class (classes.yaml
    #: ``round``): one radius, whatever fringe a mapped cup carries on one side.
    round_weight: float = 1.0
    #: Scale factors are clipped into this range relative to the model (models have real sizes).
    min_scale: float = 0.3
    max_scale: float = 3.0

    # ------------------------------------------------------------------ alignment error (AE)
    #: CAD surface samples per model for the CAD -> points direction of the AE.
    ae_model_samples: int = 1200
    #: Ours: reach (in ``alignment.FACE_SLAB`` slabs, 5 cm) within which an observed face of the
    #: same direction makes a CAD face count in the fits' CAD -> observed term (the AE uses 1):
    #: shelves seen through an open door do not make a fridge's unseen top count.
    fit_face_reach: int = 3
    #: Observed points used to evaluate AE (random subsample; all when fewer).
    ae_points: int = 2000
    #: Observed points used as surfels for the CAD -> points direction (denser is more exact).
    surfel_points: int = 8000
    #: A CAD sample counts in the CAD -> points direction when the observation covers at least
    #: this fraction of the CAD area facing the sample's direction (``alignment.visible_samples``).
    visible_min_coverage: float = 0.25
    #: Ours: selection score = AE * (1 + front_ae_factor * front cost) * (1 + class_ae_factor * other class):
    #: a flipped front must fit clearly better to win (it is a tie-breaker, not a veto).
    front_ae_factor: float = 0.5
    class_ae_factor: float = 0.25

    # ------------------------------------------------------------------ articulation
    #: Coarse grid values per joint, then refinement values around the best.
    joint_grid: int = 12
    joint_refine: int = 7
    #: Points (not explained by the rest of the model) used per joint.
    joint_points: int = 200
    #: Coordinate-descent passes over the joints at most; a pass after the first searches again only the
    #: joints another joint's change came after (``articulation.estimate_joint_values``).
    joint_passes: int = 3
    #: Estimated openings smaller than these (rad for revolute, m for prismatic joints) are taken
    #: as closed: they are within what a pose/scale error of a few mm explains.
    joint_snap_angle: float = 0.0873  # 5 degrees
    joint_snap_shift: float = 0.04
    #: Ours, articulated models: extra rounds of (joint fit of pose and open joints, 1-D joint
    #: search) after the first, taken while the joints or the pose still move, and the LM
    #: evaluations of each extra round. A second extra round changed no figure of the benchmark
    #: suite (poses, joint values, AE, stillness) and cost time on the largest objects.
    refine_rounds: int = 1
    refine_max_nfev: int = 15
    #: Ours: the best candidate's other front layouts (doors, drawers, their counts and hinge sides;
    #: ``cad.layouts``) get full fits too, when it is a procedural model of a class with layouts:
    #: a library without the object's front otherwise gives it another layout's joints and a
    #: carcass stretched over the parts it cannot open.
    layout_search: bool = True
    #: Ours: relative score a layout variant must gain over the library's own model to replace it.
    layout_margin: float = 0.05
    #: Ours: the layouts are searched when a part of the best candidate is open or at least
    #: ``layout_outlier_share`` of the points lie farther than ``layout_outlier_m`` from it; the
    #: ``layout_fits`` variants with the lowest AE at the screened pose get the full fit.
    layout_outlier_m: float = 0.03
    layout_outlier_share: float = 0.01
    layout_fits: int = 1

    # ------------------------------------------------------------------ acceptance ("never worse than the observation")
    #: An observed surface point or a visible CAD sample closer than this (m) to the other side counts
    #: as explained / covered (``AlignmentError.coverage``, ``view_coverage``).
    coverage_distance: float = 0.02
    #: Stage 4 keeps a CAD model only when it explains the observation (``acceptance``): the paper's
    #: AE (observed -> CAD RMS, Sec. 4.3) and the two-sided AE at most ``clip(accept_ae_rel * box
    #: diagonal, accept_ae_min, accept_ae_max)`` and the visible-surface coverage (``view_coverage``)
    #: at least ``accept_min_coverage``; otherwise the object is exported as its observed mesh.
    #: Set from the selected fits that are right (pose success) on the four suite scenes (ground-truth
    #: entities, 64 objects; bench-small and bench-kitchen mapped, 10; ``tools/real_data/cad_gate_data.py``):
    #: their AE reaches 1.5 % of the box diagonal above 0.5 m (a chair: 18 mm at 1.2 m), 2.2 % below
    #: (a mapped bottle: 4.5 mm at 0.21 m), 28.8 mm at most (a sofa, 2.3 m); their coverage is 0.39 at
    #: least (that sofa), 0.57 for every other. The gate keeps all 74 of them; a mapped chair fitted
    #: 77 mm off its points (coverage 0.06) is the kind it drops.
    accept_gate: bool = True
    accept_ae_min: float = 0.01
    accept_ae_rel: float = 0.02
    accept_ae_max: float = 0.03
    accept_min_coverage: float = 0.35
    #: Size agreement (``acceptance``): the accepted models whose two-sided AE is within
    #: ``size_spread_ae_ratio`` x the chosen one's must agree on every fitted extent within this share;
    #: otherwise the observation does not determine the size and the object keeps its observed mesh.
    #: 0 turns the test off.
    accept_max_size_spread: float = 0.3
    size_spread_ae_ratio: float = 1.5
    #: Class sizes (``acceptance.outside_class_sizes``): a fitted model whose extents (its two horizontal
    #: ones sorted, then its height) fall below the smallest or above the largest of its class's models in
    #: the library by more than this factor stands for a size no model of the class has; it was stretched
    #: or shrunk to a part of the object (a book's corner above a shelf's edge, a cup's rim over a shelf
    #: board) and the object keeps its observed mesh. 0 turns the test off.
    accept_class_size_factor: float = 1.25
    #: Turned in the fit (``acceptance.turned_in_fit``): a fully fitted model whose yaw the fit turned more
    #: than this (degrees) away from the orientation it was matched in (the observed box's or a large
    #: vertical plane's axes) slid into a pose that covers the points seen without matching the outline
    #: (a table whose top was half hidden under its load, turned 26 degrees in every draw) and is not kept;
    #: round classes, whose yaw the fit may turn freely, are not tested. The same 20 degrees a layout
    #: variant may turn (``replace_object.LAYOUT_YAW_TOL``). 0 turns the test off.
    accept_max_fit_turn_deg: float = 20.0
    #: Invented surface (``acceptance.invented_surface``): a fully fitted model whose surface in view is
    #: mostly not observed (``view_coverage`` below ``accept_invented_coverage``) and, on average, farther
    #: from the observed surface than ``accept_invented_ae_ratio`` x the AE limit (``ae_model``) shows
    #: more of itself than the camera saw of the object, and where it shows it is a guess: not kept. On
    #: the protocol's 24 saved maps the placements with ``ae_model`` over 2x the limit and coverage
    #: under 0.5 were gen-7373's corner cabinet in all three draws (seen 0.75 of 0.88 m wide behind a
    #: chair, fitted 12-15 cm off); right ones: chairs (legs unmapped: 1.9-3.0x, coverage 0.57-0.72)
    #: and half-seen fridges (coverage 0.36, 1.4-1.7x). 0 turns the test off.
    accept_invented_ae_ratio: float = 2.0
    accept_invented_coverage: float = 0.5
    #: A model of another (interchangeable) class replaces the best model of the detected class only
    #: when its two-sided AE is at most ``1 - class_margin`` times that one's: 0.2 is the tie the
    #: selection score already gives the detected class (``class_ae_factor`` 0.25: 1 / 1.25 = 0.8),
    #: now held against a fitted model of that class (``detected_class_fit``). On the suite, other
    #: classes' best fits came within 1.0x (cabinet/wardrobe, both right), 0.88x (a mapped table against
    #: a desk, both wrong) and 2.4x of the detected class's.
    class_margin: float = 0.2
    #: Ours: when no model of the detected class is among the ``top_k`` matches, its two best
    #: orientations join them; when none reaches the full fit (``screen_keep``), its best screened
    #: candidate gets one too, so the class margin compares fitted models.
    detected_class_fit: bool = True

    #: Random seed of every subsample (deterministic results).
    seed: int = 0

    # ------------------------------------------------------------------ execution
    #: Processes replacing objects in parallel (``workers``): 0 = one per usable CPU (at most 4),
    #: 1 = in this process. Objects are independent until the physical check; results are identical.
    workers: int = 0
    #: A scene (or update) with fewer objects to (re)match than this stays in-process while no
    #: worker runs yet: starting them (a fork server importing Open3D, cold caches in each worker)
    #: costs 1.5-2 s, about what they save on 15-18 objects (a real 10-object scene took 2.0 s
    #: in-process, 3.7 s through fresh workers); once running they are warm and take every update.
    parallel_min_objects: int = 12

    def __post_init__(self) -> None:
        if self.method not in ("ours", "paper"):
            raise ValueError(f"method must be 'ours' or 'paper', got {self.method!r}")
        for name in ("top_k", "screen_keep", "screen_points", "align_points", "joint_grid", "ae_points"):
            if int(getattr(self, name)) < 1:
                raise ValueError(f"{name} must be >= 1")
        if not 0.0 < self.min_scale < 1.0 < self.max_scale:
            raise ValueError("need 0 < min_scale < 1 < max_scale")
        if self.workers < 0:
            raise ValueError("workers must be >= 0 (0: one per usable CPU, 1: in-process)")
        if not 0.0 <= self.load_shadow_elevation_deg < 90.0:
            raise ValueError("load_shadow_elevation_deg must be in [0, 90)")
        if self.robust_scale <= 0.0:
            raise ValueError("robust_scale must be positive")
        if self.layout_margin < 0.0:
            raise ValueError("layout_margin must be >= 0")
        if self.layout_outlier_m <= 0.0 or not 0.0 <= self.layout_outlier_share <= 1.0 or self.layout_fits < 0:
            raise ValueError("need layout_outlier_m > 0, 0 <= layout_outlier_share <= 1 and layout_fits >= 0")
        if self.coverage_distance <= 0.0:
            raise ValueError("coverage_distance must be positive")
        if not self.unknown_surface_m >= 0.0:
            raise ValueError("unknown_surface_m must be >= 0")
        if not 0.0 < self.accept_ae_min <= self.accept_ae_max or self.accept_ae_rel < 0.0:
            raise ValueError("need 0 < accept_ae_min <= accept_ae_max and accept_ae_rel >= 0")
        if not 0.0 <= self.accept_min_coverage <= 1.0:
            raise ValueError("accept_min_coverage must be within [0, 1]")
        if not (self.accept_class_size_factor == 0.0 or self.accept_class_size_factor >= 1.0):
            raise ValueError("accept_class_size_factor must be 0 (off) or >= 1")
        if self.accept_invented_ae_ratio < 0.0 or not 0.0 <= self.accept_invented_coverage <= 1.0:
            raise ValueError("need accept_invented_ae_ratio >= 0 (0: off) and accept_invented_coverage in [0, 1]")
        if not 0.0 <= self.accept_max_fit_turn_deg <= 180.0:
            raise ValueError("accept_max_fit_turn_deg must be in [0, 180] degrees (0: off)")
        if self.accept_max_size_spread < 0.0 or self.size_spread_ae_ratio < 1.0:
            raise ValueError("need accept_max_size_spread >= 0 and size_spread_ae_ratio >= 1")
        if not 0.0 <= self.class_margin < 1.0:
            raise ValueError("class_margin must be within [0, 1)")


__all__ = ["CadReplacementConfig", "Method"]
