"""Procedural rigid furniture: table, desk, chair, sofa, bed, shelf (bookcase).

Every builder takes the sampled parameter dict (which it may complete with derived values such as
a chair's overall ``height``) and returns an ``Assembly``. The overall extents of the built model
are exactly ``(depth, width, height)`` of the final parameter dict (x, y, z).
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from cad_replacement.cad.assembly import Assembly, circle, rectangle
from cad_replacement.cad.params import Choice, IntRange, ParamSpec, ParamValue, Uniform
from cad_replacement.cad.shapes import FABRIC, FUSE, LIGHT_WOOD, WHITE, WOOD, Cavity, legs, shelf_levels

Params = dict[str, ParamValue]

# ---------------------------------------------------------------- parameter tables (metres)
TABLE_PARAMS: ParamSpec = {
    "top_shape": Choice(("rectangular", "round"), (0.7, 0.3)),  # round: diameter = width = depth
    "base": Choice(("legs", "pedestal")),
    "width": Uniform(0.8, 1.8),
    "depth": Uniform(0.6, 1.0),
    "height": Uniform(0.70, 0.78),
    "top_thickness": Uniform(0.025, 0.05),
    "leg_size": Uniform(0.04, 0.08),
    "leg_inset": Uniform(0.0, 0.08),
    "round_legs": Choice(("no", "yes")),
    "apron_height": Uniform(0.0, 0.10),
}
DESK_PARAMS: ParamSpec = {
    "style": Choice(("legs", "panels", "pedestal")),
    "width": Uniform(1.0, 1.8),
    "depth": Uniform(0.55, 0.80),
    "height": Uniform(0.72, 0.78),
    "top_thickness": Uniform(0.02, 0.04),
    "leg_size": Uniform(0.04, 0.07),
    "panel_thickness": Uniform(0.018, 0.03),
    "pedestal_width": Uniform(0.35, 0.45),
    "pedestal_side": Choice(("left", "right")),
    "modesty_panel": Choice(("yes", "no")),
}
CHAIR_PARAMS: ParamSpec = {
    "width": Uniform(0.40, 0.55),
    "depth": Uniform(0.42, 0.56),
    "seat_height": Uniform(0.42, 0.50),
    "back_height": Uniform(0.30, 0.50),  # above the seat
    "seat_thickness": Uniform(0.03, 0.08),
    "leg_size": Uniform(0.025, 0.05),
    "back_thickness": Uniform(0.02, 0.06),
    "back_style": Choice(("solid", "slats")),
    "arms": Choice(("no", "yes"), (0.7, 0.3)),
    "round_legs": Choice(("no", "yes")),
}
SOFA_PARAMS: ParamSpec = {
    "width": Uniform(1.4, 2.4),
    "depth": Uniform(0.8, 1.0),
    "height": Uniform(0.75, 0.95),
    "seat_height": Uniform(0.40, 0.48),
    "arm_width": Uniform(0.08, 0.25),
    "arm_height": Uniform(0.55, 0.70),
    "back_thickness": Uniform(0.15, 0.25),
    "cushions": IntRange(1, 3),
    "base": Choice(("legs", "plinth")),
    "leg_height": Uniform(0.05, 0.15),
}
BED_PARAMS: ParamSpec = {
    "width": Uniform(0.9, 1.9),
    "depth": Uniform(1.95, 2.25),  # length; the headboard is at the back (-x)
    "height": Uniform(0.8, 1.2),  # headboard top
    "frame_height": Uniform(0.2, 0.4),
    "mattress_thickness": Uniform(0.15, 0.3),
    "headboard_thickness": Uniform(0.04, 0.1),
    "footboard": Choice(("no", "yes")),
    "base": Choice(("legs", "plinth")),
    "leg_height": Uniform(0.08, 0.2),
    "pillows": IntRange(0, 2),
}
SHELF_PARAMS: ParamSpec = {
    "width": Uniform(0.6, 1.2),
    "depth": Uniform(0.25, 0.45),
    "height": Uniform(0.8, 2.0),
    "levels": IntRange(2, 6),  # usable levels inside (bottom board + shelves); the top is extra
    "board_thickness": Uniform(0.015, 0.03),
    "back": Choice(("panel", "open")),
    "plinth": Uniform(0.0, 0.08),
}

#: Classes whose models carry a varying number of support levels at varying heights (what stands in
#: them rests on one: a library needs enough of them to offer the observed heights).
LEVELLED = frozenset({"shelf"})

#: Smallest free height between bookcase levels (m); more levels than fit are dropped.
MIN_LEVEL_PITCH = 0.18
#: Pillow height on a bed (m).
PILLOW_HEIGHT = 0.12
#: Back panel thickness of a bookcase (m).
BACK_PANEL = 0.008


def _f(p: Params, key: str) -> float:
    return float(p[key])


def build_table(p: Params) -> Assembly:
    asm = Assembly("table")
    body = asm.link("body", WOOD)
    round_top = p["top_shape"] == "round"
    if round_top:
        p["depth"] = p["width"]
    w, d, h, tt = _f(p, "width"), _f(p, "depth"), _f(p, "height"), _f(p, "top_thickness")
    leg = min(_f(p, "leg_size"), 0.15 * min(w, d))
    inset = min(_f(p, "leg_inset"), 0.1 * min(w, d))
    leg_top = h - tt + FUSE
    if round_top:
        body.cylinder((0.0, 0.0, h - 0.5 * tt), 0.5 * w, tt)
        asm.support(h, circle(0.0, 0.0, 0.5 * w))
    else:
        body.box((-0.5 * d, -0.5 * w, h - tt), (0.5 * d, 0.5 * w, h))
        asm.support(h, rectangle(-0.5 * d, 0.5 * d, -0.5 * w, 0.5 * w))
    if p["base"] == "legs":
        if round_top:
            half = (0.5 * w - inset) / math.sqrt(2.0)
            ex, ey = half, half
        else:
            ex, ey = 0.5 * d - inset, 0.5 * w - inset
        legs(body, -ex, ex, -ey, ey, 0.0, leg_top, leg, p["round_legs"] == "yes")
        apron = min(_f(p, "apron_height"), 0.3 * h)
        if apron > 0.03 and not round_top:
            t = 0.02
            z0 = h - tt - apron
            body.box((-ex + 0.5 * leg - t, -ey, z0), (-ex + 0.5 * leg, ey, leg_top))
            body.box((ex - 0.5 * leg, -ey, z0), (ex - 0.5 * leg + t, ey, leg_top))
            body.box((-ex, -ey + 0.5 * leg - t, z0), (ex, -ey + 0.5 * leg, leg_top))
            body.box((-ex, ey - 0.5 * leg, z0), (ex, ey - 0.5 * leg + t, leg_top))
    elif round_top:
        body.cylinder((0.0, 0.0, 0.5 * leg_top), 1.2 * leg, leg_top)
        body.cylinder((0.0, 0.0, 0.015), 0.3 * w, 0.03)
    else:  # trestle: two columns with feet along x
        for y in (-0.3 * w, 0.3 * w):
            body.box((-0.5 * leg, y - 0.5 * leg, 0.0), (0.5 * leg, y + 0.5 * leg, leg_top))
            body.box((-0.4 * d, y - 0.5 * leg, 0.0), (0.4 * d, y + 0.5 * leg, 0.04))
        body.box((-0.5 * leg, -0.3 * w, 0.35 * h), (0.5 * leg, 0.3 * w, 0.35 * h + 0.05))
    return asm


def build_desk(p: Params) -> Assembly:
    asm = Assembly("desk")
    body = asm.link("body", LIGHT_WOOD)
    w, d, h, tt = _f(p, "width"), _f(p, "depth"), _f(p, "height"), _f(p, "top_thickness")
    pt = _f(p, "panel_thickness")
    top_z = h - tt
    body.box((-0.5 * d, -0.5 * w, top_z), (0.5 * d, 0.5 * w, h))
    asm.support(h, rectangle(-0.5 * d, 0.5 * d, -0.5 * w, 0.5 * w))
    style = p["style"]
    if style == "legs":
        leg = _f(p, "leg_size")
        legs(body, -0.5 * d, 0.5 * d, -0.5 * w, 0.5 * w, 0.0, top_z + FUSE, leg)
    else:
        left_y = 0.5 * w
        right_y = -0.5 * w
        if style == "pedestal":
            pw = min(_f(p, "pedestal_width"), 0.45 * w)
            if p["pedestal_side"] == "left":
                body.box((-0.5 * d, left_y - pw, 0.0), (0.5 * d, left_y, top_z + FUSE))
                left_y -= pw - pt
            else:
                body.box((-0.5 * d, right_y, 0.0), (0.5 * d, right_y + pw, top_z + FUSE))
                right_y += pw - pt
        body.box((-0.5 * d, left_y - pt, 0.0), (0.5 * d, left_y, top_z + FUSE))
        body.box((-0.5 * d, right_y, 0.0), (0.5 * d, right_y + pt, top_z + FUSE))
        if p["modesty_panel"] == "yes":
            body.box(
                (-0.5 * d + 0.02, right_y + pt - FUSE, 0.45 * h),
                (-0.5 * d + 0.02 + pt, left_y - pt + FUSE, top_z + FUSE),
            )
    return asm


def build_chair(p: Params) -> Assembly:
    asm = Assembly("chair")
    body = asm.link("body", WOOD)
    w, d = _f(p, "width"), _f(p, "depth")
    sh, bh, st = _f(p, "seat_height"), _f(p, "back_height"), _f(p, "seat_thickness")
    leg, bt = min(_f(p, "leg_size"), 0.15 * w), _f(p, "back_thickness")
    p["height"] = sh + bh
    x0, x1, y0, y1 = -0.5 * d, 0.5 * d, -0.5 * w, 0.5 * w
    body.box((x0, y0, sh - st), (x1, y1, sh))
    legs(body, x0, x1, y0, y1, 0.0, sh - st + FUSE, leg, p["round_legs"] == "yes")
    top = sh + bh
    if p["back_style"] == "solid":
        body.box((x0, y0, sh - FUSE), (x0 + bt, y1, top))
    else:
        rail = min(0.08, 0.3 * bh)
        for y in (y0, y1 - leg):
            body.box((x0, y, sh - FUSE), (x0 + max(bt, leg), y + leg, top))
        body.box((x0, y0, top - rail), (x0 + bt, y1, top))
        for y in np.linspace(y0 + leg, y1 - leg, 5)[1:-1]:
            body.box((x0, y - 0.012, sh - FUSE), (x0 + 0.5 * bt, y + 0.012, top - rail + FUSE))
    if p["arms"] == "yes":
        arm_z = sh + min(0.22, 0.7 * bh)
        for y in (y0, y1 - 0.04):
            body.box((x0 + bt - FUSE, y, arm_z - 0.03), (x1 - 0.03, y + 0.04, arm_z))
            body.box((x1 - 0.08, y + 0.01, sh - FUSE), (x1 - 0.05, y + 0.03, arm_z - 0.03 + FUSE))
    asm.support(sh, rectangle(x0 + bt, x1, y0, y1))
    return asm


def build_sofa(p: Params) -> Assembly:
    asm = Assembly("sofa")
    body = asm.link("body", FABRIC)
    w, d, h = _f(p, "width"), _f(p, "depth"), _f(p, "height")
    sh, aw, ah, bt = (
        _f(p, "seat_height"),
        min(_f(p, "arm_width"), 0.2 * w),
        _f(p, "arm_height"),
        _f(p, "back_thickness"),
    )
    bt = min(bt, 0.4 * d)
    lh = _f(p, "leg_height") if p["base"] == "legs" else 0.0
    lh = min(lh, 0.4 * sh)
    ah = float(np.clip(ah, sh + 0.05, h))
    p["arm_height"] = ah
    ct = min(0.15, 0.5 * (sh - lh))
    x0, x1, y0, y1 = -0.5 * d, 0.5 * d, -0.5 * w, 0.5 * w
    body.box((x0, y0 + aw - FUSE, lh), (x1, y1 - aw + FUSE, sh - ct))
    for ya, yb in ((y0, y0 + aw), (y1 - aw, y1)):
        body.box((x0, ya, lh), (x1, yb, ah))
        asm.support(ah, rectangle(x0, x1, ya, yb))
    body.box((x0, y0 + aw - FUSE, lh), (x0 + bt, y1 - aw + FUSE, h))
    n = int(p["cushions"])
    gap = 0.01
    span = (w - 2 * aw - (n - 1) * gap) / n
    for i in range(n):
        ya = y0 + aw + i * (span + gap)
        body.box((x0 + bt - FUSE, ya, sh - ct - FUSE), (x1, ya + span, sh))
    if lh > 0.0:
        legs(body, x0 + 0.03, x1 - 0.03, y0 + 0.03, y1 - 0.03, 0.0, lh + FUSE, 0.04, True)
    asm.support(sh, rectangle(x0 + bt, x1, y0 + aw, y1 - aw))
    return asm


def build_bed(p: Params) -> Assembly:
    asm = Assembly("bed")
    body = asm.link("body", WOOD)
    w, d = _f(p, "width"), _f(p, "depth")
    fh, mt, ht = _f(p, "frame_height"), _f(p, "mattress_thickness"), _f(p, "headboard_thickness")
    lh = min(_f(p, "leg_height"), 0.5 * fh) if p["base"] == "legs" else 0.0
    top = fh + mt
    n_pillows = int(p["pillows"])
    h = max(_f(p, "height"), top + (PILLOW_HEIGHT if n_pillows else 0.0) + 0.05)
    p["height"] = h
    x0, x1, y0, y1 = -0.5 * d, 0.5 * d, -0.5 * w, 0.5 * w
    body.box((x0, y0, 0.0), (x0 + ht, y1, h))
    foot = 0.04 if p["footboard"] == "yes" else 0.0
    body.box((x0 + ht - FUSE, y0, lh), (x1 - foot + (FUSE if foot else 0.0), y1, fh))
    if foot:
        body.box((x1 - foot, y0, 0.0), (x1, y1, top + 0.5 * (h - top)))
    if lh > 0.0:
        legs(body, x0 + ht, x1 - foot, y0, y1, 0.0, lh + FUSE, 0.06)
    m = 0.02
    mattress = asm.link("mattress", WHITE)
    mattress.box((x0 + ht, y0 + m, fh), (x1 - foot - m, y1 - m, top))
    asm.joint("mattress_fixed", "fixed", "body", "mattress", anchor=(0.0, 0.0, fh))
    if n_pillows:
        pw = (w - 2 * m - 0.05 * (n_pillows + 1)) / n_pillows
        for i in range(n_pillows):
            ya = y0 + m + 0.05 + i * (pw + 0.05)
            mattress.box((x0 + ht + 0.05, ya, top - FUSE), (x0 + ht + 0.45, ya + pw, top + PILLOW_HEIGHT))
    asm.support(top, rectangle(x0 + ht, x1 - foot - m, y0 + m, y1 - m), link="mattress")
    return asm


def build_shelf(p: Params) -> Assembly:
    asm = Assembly("shelf")
    body = asm.link("body", LIGHT_WOOD)
    w, d, h, bt = _f(p, "width"), _f(p, "depth"), _f(p, "height"), _f(p, "board_thickness")
    plinth = _f(p, "plinth") if _f(p, "plinth") > 0.01 else 0.0
    x0, x1, y0, y1 = -0.5 * d, 0.5 * d, -0.5 * w, 0.5 * w
    body.box((x0, y0, 0.0), (x1, y0 + bt, h))
    body.box((x0, y1 - bt, 0.0), (x1, y1, h))
    body.box((x0, y0, h - bt), (x1, y1, h))
    body.box((x0, y0, plinth), (x1, y1, plinth + bt))
    if plinth:
        body.box((x1 - 0.03, y0 + bt - FUSE, 0.0), (x1 - 0.01, y1 - bt + FUSE, plinth + FUSE))
    back = p["back"] == "panel"
    if back:
        body.box((x0, y0, 0.0), (x0 + BACK_PANEL, y1, h))
    cavity = Cavity(x0 + (BACK_PANEL if back else 0.0), x1, y0 + bt, y1 - bt, plinth + bt, h - bt)
    inner = cavity.z1 - cavity.z0
    max_levels = max(1, int((inner + bt) // (MIN_LEVEL_PITCH + bt)))
    levels = int(np.clip(int(p["levels"]), 1, max_levels))
    p["levels"] = levels
    shelf_levels(asm, body, cavity, levels - 1, bt, enclosed=False, into_back=back)
    asm.support(h, rectangle(x0, x1, y0, y1))
    return asm


SPECS: dict[str, ParamSpec] = {
    "table": TABLE_PARAMS,
    "desk": DESK_PARAMS,
    "chair": CHAIR_PARAMS,
    "sofa": SOFA_PARAMS,
    "bed": BED_PARAMS,
    "shelf": SHELF_PARAMS,
}
BUILDERS: dict[str, Callable[[Params], Assembly]] = {
    "table": build_table,
    "desk": build_desk,
    "chair": build_chair,
    "sofa": build_sofa,
    "bed": build_bed,
    "shelf": build_shelf,
}
