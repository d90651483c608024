"""Procedural articulated objects: fridge, microwave, cabinet, oven, dishwasher, wardrobe.

The root link ``body`` is a carcass open to the front (+x); doors are revolute links, drawers and
racks prismatic links (see ``shapes``). Overall extents are exactly ``(depth, width, height)``:
the carcass depth is what remains after the front thickness and handle protrusion.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from cad_replacement.cad.assembly import Assembly, LinkBuilder, rectangle
from cad_replacement.cad.params import Choice, IntRange, ParamSpec, ParamValue, Uniform
from cad_replacement.cad.shapes import (
    DARK,
    FRONT_GAP,
    FUSE,
    LIGHT_WOOD,
    STEEL,
    TRAY_CLEARANCE,
    WHITE,
    WOOD,
    Cavity,
    FrontStyle,
    HingeSide,
    carcass,
    door_row,
    drawer,
    drop_door,
    legs,
    shelf_levels,
    tray,
)

Params = dict[str, ParamValue]

FRIDGE_PARAMS: ParamSpec = {
    "layout": Choice(("single", "top_freezer", "bottom_freezer", "side_by_side")),
    "width": Uniform(0.55, 0.95),
    "depth": Uniform(0.60, 0.80),
    "height": Uniform(1.45, 1.95),
    "wall": Uniform(0.04, 0.06),
    "door_thickness": Uniform(0.04, 0.07),
    "handle_protrusion": Uniform(0.03, 0.06),
    "shelves": IntRange(2, 4),
    "hinge_side": Choice(("left", "right")),
    "freezer_fraction": Uniform(0.25, 0.38),
}
MICROWAVE_PARAMS: ParamSpec = {
    "width": Uniform(0.44, 0.60),
    "depth": Uniform(0.32, 0.45),
    "height": Uniform(0.25, 0.35),
    "wall": Uniform(0.01, 0.02),
    "door_thickness": Uniform(0.02, 0.04),
    "panel_fraction": Uniform(0.20, 0.30),  # control panel share of the width (right side)
    "handle": Choice(("bar", "none")),
    "handle_protrusion": Uniform(0.015, 0.03),
    "feet": Uniform(0.0, 0.015),
}
CABINET_PARAMS: ParamSpec = {
    "layout": Choice(("doors", "drawers", "drawers_over_doors", "open_over_doors")),
    "width": Uniform(0.40, 1.60),
    "depth": Uniform(0.35, 0.62),
    "height": Uniform(0.50, 1.10),
    "wall": Uniform(0.015, 0.025),
    "front_thickness": Uniform(0.016, 0.022),
    "handle_protrusion": Uniform(0.02, 0.04),
    "base": Choice(("plinth", "legs")),
    "base_height": Uniform(0.0, 0.12),
    "drawer_count": IntRange(2, 5),
    "shelves": IntRange(0, 2),
    "hinge_side": Choice(("left", "right")),
}
OVEN_PARAMS: ParamSpec = {
    "style": Choice(("range", "wall")),  # range: cooktop + backguard; wall: built-in box
    "width": Uniform(0.50, 0.76),
    "depth": Uniform(0.55, 0.68),
    "height": Uniform(0.60, 0.95),
    "wall": Uniform(0.03, 0.05),
    "door_thickness": Uniform(0.03, 0.05),
    "handle_protrusion": Uniform(0.03, 0.05),
    "panel_height": Uniform(0.08, 0.14),
    "drawer": Choice(("yes", "no")),
    "racks": IntRange(1, 3),
    "backguard_height": Uniform(0.05, 0.15),
}
DISHWASHER_PARAMS: ParamSpec = {
    "width": Uniform(0.45, 0.60),
    "depth": Uniform(0.55, 0.65),
    "height": Uniform(0.80, 0.87),
    "wall": Uniform(0.02, 0.04),
    "door_thickness": Uniform(0.04, 0.07),
    "handle_protrusion": Uniform(0.02, 0.04),
    "kick_height": Uniform(0.06, 0.12),
    "racks": IntRange(1, 2),
}
WARDROBE_PARAMS: ParamSpec = {
    "width": Uniform(0.80, 2.00),
    "depth": Uniform(0.50, 0.65),
    "height": Uniform(1.70, 2.20),
    "wall": Uniform(0.018, 0.03),
    "door_thickness": Uniform(0.018, 0.025),
    "handle_protrusion": Uniform(0.02, 0.04),
    "doors": IntRange(1, 4),
    "bottom_drawers": IntRange(0, 2),
    "hat_shelf": Uniform(0.25, 0.40),  # distance of the hat shelf below the top
    "base_height": Uniform(0.03, 0.10),
    "hinge_side": Choice(("left", "right")),
}

#: Opening limits (rad) of outer-hinged doors per class.
FRIDGE_DOOR_LIMIT = 2.0
MICROWAVE_DOOR_LIMIT = 1.75
FURNITURE_DOOR_LIMIT = 0.6 * math.pi
#: Height of one drawer row (m) in "drawers over doors" cabinets and of wardrobe drawers.
DRAWER_ROW = 0.18
#: Narrowest / widest single furniture door (m); decides how many doors a front gets.
MIN_DOOR_WIDTH = 0.3
MAX_DOOR_WIDTH = 0.65
#: Shallow front frame strip behind door gaps (m).
MULLION_DEPTH = 0.02


def _f(p: Params, key: str) -> float:
    return float(p[key])


def _side(p: Params) -> HingeSide:
    return "left" if p["hinge_side"] == "left" else "right"


def _board_z(link: LinkBuilder, cav: Cavity, z: float, t: float) -> None:
    """Horizontal divider board spanning the cavity at height ``z`` (fused into the walls)."""
    link.box((cav.x0 - FUSE, cav.y0 - FUSE, z - 0.5 * t), (cav.x1, cav.y1 + FUSE, z + 0.5 * t))


def _mullions(link: LinkBuilder, gaps: list[tuple[float, float]], x_front: float, z0: float, z1: float) -> None:
    for ya, yb in gaps:
        link.box((x_front - MULLION_DEPTH, ya, z0 - FUSE), (x_front, yb, z1 + FUSE))


def _door_count(width: float, requested: int | None = None) -> int:
    lo = max(1, math.ceil(width / MAX_DOOR_WIDTH))
    hi = max(lo, math.floor(width / MIN_DOOR_WIDTH))
    return int(np.clip(requested if requested is not None else round(width / 0.5), lo, hi))


def _drawer_stack(
    asm: Assembly,
    prefix: str,
    *,
    x_front: float,
    y0: float,
    y1: float,
    z0: float,
    z1: float,
    rows: int,
    cavity: Cavity,
    style: FrontStyle,
    first_index: int = 0,
) -> int:
    """``rows`` drawers stacked in ``z0..z1`` (fronts separated by ``FRONT_GAP``); returns next index."""
    h = (z1 - z0 - (rows - 1) * FRONT_GAP) / rows
    for r in range(rows):
        za = z0 + r * (h + FRONT_GAP)
        drawer(
            asm,
            "body",
            f"{prefix}{first_index + r}",
            x_front=x_front,
            front=(y0, y1, za, za + h),
            cavity=cavity,
            style=style,
        )
    return first_index + rows


def build_fridge(p: Params) -> Assembly:
    asm = Assembly("fridge")
    body = asm.link("body", WHITE)
    w, d, h, wall = _f(p, "width"), _f(p, "depth"), _f(p, "height"), _f(p, "wall")
    dt, hp = _f(p, "door_thickness"), _f(p, "handle_protrusion")
    x0 = -0.5 * d
    xf = 0.5 * d - dt - hp
    y0, y1 = -0.5 * w, 0.5 * w
    cav = carcass(body, x0, xf, y0, y1, 0.0, h, wall)
    asm.support(h, rectangle(x0, xf, y0, y1))
    layout = p["layout"]
    ff = _f(p, "freezer_fraction")
    shelves = int(p["shelves"])
    side = _side(p)

    def style(door_h: float) -> FrontStyle:
        return FrontStyle(dt, hp, WHITE, STEEL, handle_length=float(np.clip(0.4 * door_h, 0.12, 0.6)))

    def compartment(c: Cavity, n: int) -> None:
        shelf_levels(asm, body, c, n, 0.01, enclosed=True, front_inset=0.06)

    if layout == "single":
        door_row(
            asm,
            "body",
            "door_",
            x_front=xf,
            y0=y0,
            y1=y1,
            z0=0.0,
            z1=h,
            count=1,
            style=style(h),
            single_side=side,
            outer_limit=FRIDGE_DOOR_LIMIT,
            handle_z=0.6 * h,
        )
        compartment(cav, shelves)
    elif layout in ("top_freezer", "bottom_freezer"):
        z_div = h * (1.0 - ff) if layout == "top_freezer" else h * ff
        _board_z(body, cav, z_div, wall)
        lower = Cavity(cav.x0, cav.x1, cav.y0, cav.y1, cav.z0, z_div - 0.5 * wall)
        upper = Cavity(cav.x0, cav.x1, cav.y0, cav.y1, z_div + 0.5 * wall, cav.z1)
        zl1, zu0 = z_div - 0.5 * FRONT_GAP, z_div + 0.5 * FRONT_GAP
        door_row(
            asm,
            "body",
            "door_lower_",
            x_front=xf,
            y0=y0,
            y1=y1,
            z0=0.0,
            z1=zl1,
            count=1,
            style=style(zl1),
            single_side=side,
            outer_limit=FRIDGE_DOOR_LIMIT,
            handle_z=zl1 - 0.3 * zl1,
        )
        door_row(
            asm,
            "body",
            "door_upper_",
            x_front=xf,
            y0=y0,
            y1=y1,
            z0=zu0,
            z1=h,
            count=1,
            style=style(h - zu0),
            single_side=side,
            outer_limit=FRIDGE_DOOR_LIMIT,
            handle_z=zu0 + 0.3 * (h - zu0),
        )
        main, freezer = (lower, upper) if layout == "top_freezer" else (upper, lower)
        compartment(main, shelves)
        compartment(freezer, 1)
    else:  # side by side: freezer on the left (+y)
        y_div = y1 - (0.35 + 0.3 * ff) * w
        body.box((cav.x0 - FUSE, y_div - 0.5 * wall, cav.z0 - FUSE), (cav.x1, y_div + 0.5 * wall, cav.z1 + FUSE))
        door_row(
            asm,
            "body",
            "door_left_",
            x_front=xf,
            y0=y_div + 0.5 * FRONT_GAP,
            y1=y1,
            z0=0.0,
            z1=h,
            count=1,
            style=style(h),
            single_side="left",
            outer_limit=FRIDGE_DOOR_LIMIT,
            handle_z=0.55 * h,
        )
        door_row(
            asm,
            "body",
            "door_right_",
            x_front=xf,
            y0=y0,
            y1=y_div - 0.5 * FRONT_GAP,
            z0=0.0,
            z1=h,
            count=1,
            style=style(h),
            single_side="right",
            outer_limit=FRIDGE_DOOR_LIMIT,
            handle_z=0.55 * h,
        )
        compartment(Cavity(cav.x0, cav.x1, y_div + 0.5 * wall, cav.y1, cav.z0, cav.z1), shelves + 1)
        compartment(Cavity(cav.x0, cav.x1, cav.y0, y_div - 0.5 * wall, cav.z0, cav.z1), shelves)
    return asm


def build_microwave(p: Params) -> Assembly:
    asm = Assembly("microwave")
    body = asm.link("body", STEEL)
    w, d, h, wall = _f(p, "width"), _f(p, "depth"), _f(p, "height"), _f(p, "wall")
    dt = _f(p, "door_thickness")
    hp = _f(p, "handle_protrusion") if p["handle"] == "bar" else 0.0
    feet = _f(p, "feet") if _f(p, "feet") > 0.003 else 0.0
    x0, xf = -0.5 * d, 0.5 * d - dt - hp
    y0, y1 = -0.5 * w, 0.5 * w
    cav = carcass(body, x0, xf, y0, y1, feet, h, wall)
    pw = _f(p, "panel_fraction") * w
    # Control panel block on the right, flush with the closed door's front.
    body.box((xf - 0.05, y0, feet), (xf + dt, y0 + pw, h))
    body.box((xf - 0.05, y0 + pw - wall, cav.z0 - FUSE), (xf, y0 + pw, cav.z1 + FUSE))
    if hp > 0.0:  # knobs stay within the handle's protrusion so the overall depth is unchanged
        for i in range(3):
            zc = feet + (h - feet) * (0.3 + 0.2 * i)
            body.cylinder(
                (xf + dt + 0.25 * hp - 0.5 * FUSE, y0 + 0.5 * pw, zc), min(0.015, 0.25 * pw), 0.5 * hp + FUSE, "x"
            )
    if feet:
        legs(body, x0 + 0.02, xf - 0.02, y0 + 0.02, y1 - 0.02, 0.0, feet + FUSE, 0.02, True)
    inner = Cavity(cav.x0, cav.x1, y0 + pw, cav.y1, cav.z0, cav.z1)
    turntable_r = 0.4 * min(inner.x1 - inner.x0, inner.y1 - inner.y0)
    tc = (0.5 * (inner.x0 + inner.x1), 0.5 * (inner.y0 + inner.y1))
    body.cylinder((tc[0], tc[1], inner.z0 + 0.003 - 0.5 * FUSE), turntable_r, 0.006 + FUSE)
    asm.support(
        inner.z0, rectangle(inner.x0, inner.x1, inner.y0, inner.y1), clearance=inner.z1 - inner.z0, enclosed=True
    )
    asm.support(h, rectangle(x0, xf, y0, y1))
    style = FrontStyle(dt, hp, DARK, STEEL, handle_length=0.6 * (h - feet))
    door_row(
        asm,
        "body",
        "door_",
        x_front=xf,
        y0=y0 + pw + FRONT_GAP,
        y1=y1,
        z0=feet,
        z1=h,
        count=1,
        style=style,
        single_side="left",
        outer_limit=MICROWAVE_DOOR_LIMIT,
    )
    return asm


def _base(body: LinkBuilder, kind: str, bh: float, x0: float, xf: float, y0: float, y1: float) -> float:
    """Legs or a recessed plinth (``kind``) of height ``bh`` under a carcass; returns its bottom z."""
    if bh < 0.02:
        return 0.0
    if kind == "legs":
        legs(body, x0 + 0.02, xf - 0.02, y0 + 0.02, y1 - 0.02, 0.0, bh + FUSE, 0.04)
    else:
        body.box((x0, y0 + 0.02, 0.0), (xf - 0.05, y1 - 0.02, bh + FUSE))
    return bh


def build_cabinet(p: Params) -> Assembly:
    asm = Assembly("cabinet")
    body = asm.link("body", WOOD)
    w, d, h, wall = _f(p, "width"), _f(p, "depth"), _f(p, "height"), _f(p, "wall")
    ft, hp = _f(p, "front_thickness"), _f(p, "handle_protrusion")
    x0, xf = -0.5 * d, 0.5 * d - ft - hp
    y0, y1 = -0.5 * w, 0.5 * w
    zb = _base(body, str(p["base"]), _f(p, "base_height"), x0, xf, y0, y1)
    cav = carcass(body, x0, xf, y0, y1, zb, h, wall)
    asm.support(h, rectangle(x0, xf, y0, y1))
    style = FrontStyle(ft, hp, LIGHT_WOOD, STEEL, handle_length=0.12)
    layout = p["layout"]
    n_doors = _door_count(w)
    columns = 1 if w < 0.9 else 2

    def doors(z0: float, z1: float, c: Cavity) -> None:
        gaps = door_row(
            asm,
            "body",
            "door_",
            x_front=xf,
            y0=y0,
            y1=y1,
            z0=z0,
            z1=z1,
            count=n_doors,
            style=style,
            single_side=_side(p),
            outer_limit=FURNITURE_DOOR_LIMIT,
            handle_z=z1 - 0.1,
        )
        _mullions(body, gaps, xf, c.z0, c.z1)
        shelf_levels(asm, body, c, int(p["shelves"]), wall, enclosed=True, front_inset=0.02)

    def drawer_rows(z0: float, z1: float, rows: int, c: Cavity) -> None:
        if columns == 1:
            _drawer_stack(asm, "drawer_", x_front=xf, y0=y0, y1=y1, z0=z0, z1=z1, rows=rows, cavity=c, style=style)
            return
        body.box((c.x0 - FUSE, -0.5 * wall, c.z0 - FUSE), (c.x1, 0.5 * wall, c.z1 + FUSE))
        left = Cavity(c.x0, c.x1, 0.5 * wall, c.y1, c.z0, c.z1)
        right = Cavity(c.x0, c.x1, c.y0, -0.5 * wall, c.z0, c.z1)
        nxt = _drawer_stack(
            asm, "drawer_", x_front=xf, y0=0.5 * FRONT_GAP, y1=y1, z0=z0, z1=z1, rows=rows, cavity=left, style=style
        )
        _drawer_stack(
            asm,
            "drawer_",
            x_front=xf,
            y0=y0,
            y1=-0.5 * FRONT_GAP,
            z0=z0,
            z1=z1,
            rows=rows,
            cavity=right,
            style=style,
            first_index=nxt,
        )

    if layout == "doors":
        doors(zb, h, cav)
    elif layout == "drawers":
        rows = int(np.clip(int(p["drawer_count"]), 1, max(1, int((h - zb) // 0.1))))
        p["drawer_count"] = rows
        drawer_rows(zb, h, rows, cav)
    else:
        row = min(DRAWER_ROW, 0.35 * (h - zb))
        z_div = h - row
        _board_z(body, cav, z_div, wall)
        lower = Cavity(cav.x0, cav.x1, cav.y0, cav.y1, cav.z0, z_div - 0.5 * wall)
        upper = Cavity(cav.x0, cav.x1, cav.y0, cav.y1, z_div + 0.5 * wall, cav.z1)
        doors(zb, z_div - 0.5 * FRONT_GAP, lower)
        if layout == "drawers_over_doors":
            drawer_rows(z_div + 0.5 * FRONT_GAP, h, 1, upper)
        else:  # open compartment above the doors: a visible support level
            asm.support(upper.z0, rectangle(upper.x0, upper.x1, upper.y0, upper.y1), clearance=upper.z1 - upper.z0)
    return asm


def build_oven(p: Params) -> Assembly:
    asm = Assembly("oven")
    body = asm.link("body", STEEL)
    w, d, h, wall = _f(p, "width"), _f(p, "depth"), _f(p, "height"), _f(p, "wall")
    dt, hp = _f(p, "door_thickness"), _f(p, "handle_protrusion")
    x0, xf = -0.5 * d, 0.5 * d - dt - hp
    y0, y1 = -0.5 * w, 0.5 * w
    is_range = p["style"] == "range"
    hb = h - _f(p, "backguard_height") if is_range else h
    cav = carcass(body, x0, xf, y0, y1, 0.0, hb, wall)
    style = FrontStyle(dt, hp, DARK, STEEL, handle_length=0.6 * w)
    panel_h = min(_f(p, "panel_height"), 0.2 * hb)
    z_panel = hb - panel_h
    body.box((xf - 0.05, y0, z_panel), (xf + dt, y1, hb))
    for yk in np.linspace(y0, y1, 6)[1:-1]:
        body.cylinder((xf + dt + 0.25 * hp - 0.5 * FUSE, yk, z_panel + 0.5 * panel_h), 0.015, 0.5 * hp + FUSE, "x")
    if is_range:
        body.box((x0, y0, hb - FUSE), (x0 + 0.06, y1, h))
        r = 0.2 * min(w, xf - x0 - 0.06)
        for bx in (x0 + 0.06 + 0.25 * (xf - x0 - 0.06), x0 + 0.06 + 0.75 * (xf - x0 - 0.06)):
            for by in (-0.25 * w, 0.25 * w):
                body.cylinder((bx, by, hb + 0.005 - 0.5 * FUSE), r, 0.01 + FUSE)
        asm.support(hb, rectangle(x0 + 0.06, xf, y0, y1))
    else:
        asm.support(hb, rectangle(x0, xf, y0, y1))
    z_door0 = max(0.04, dt + 0.01)
    if p["drawer"] == "yes" and hb > 0.7:
        dh = 0.12
        za = 0.02
        z_door0 = za + dh + dt + 2 * FRONT_GAP
        _board_z(body, cav, z_door0 - 0.5 * wall, wall)
        drawer(
            asm,
            "body",
            "drawer_0",
            x_front=xf,
            front=(y0, y1, za, za + dh),
            cavity=Cavity(cav.x0, cav.x1, cav.y0, cav.y1, cav.z0, z_door0 - wall),
            style=style,
        )
    else:
        body.box((cav.x0 - FUSE, cav.y0 - FUSE, cav.z0 - FUSE), (cav.x1, cav.y1 + FUSE, z_door0))
    oven = Cavity(cav.x0, cav.x1, cav.y0, cav.y1, max(cav.z0, z_door0), z_panel)
    if z_panel - 0.5 * wall < cav.z1:
        _board_z(body, cav, z_panel - 0.5 * wall, wall)
        oven = Cavity(oven.x0, oven.x1, oven.y0, oven.y1, oven.z0, z_panel - wall)
    shelf_levels(asm, body, oven, int(p["racks"]), 0.008, enclosed=True, front_inset=0.03)
    drop_door(
        asm, "body", "door", x_front=xf, y0=y0, y1=y1, z0=z_door0, z1=z_panel - FRONT_GAP, style=style, window=True
    )
    return asm


def build_dishwasher(p: Params) -> Assembly:
    asm = Assembly("dishwasher")
    body = asm.link("body", STEEL)
    w, d, h, wall = _f(p, "width"), _f(p, "depth"), _f(p, "height"), _f(p, "wall")
    dt, hp = _f(p, "door_thickness"), _f(p, "handle_protrusion")
    kick = max(_f(p, "kick_height"), dt + 0.01)
    x0, xf = -0.5 * d, 0.5 * d - dt - hp
    y0, y1 = -0.5 * w, 0.5 * w
    cav = carcass(body, x0, xf, y0, y1, 0.0, h, wall)
    body.box((cav.x0 - FUSE, cav.y0 - FUSE, cav.z0 - FUSE), (cav.x1, cav.y1 + FUSE, kick))
    inner = Cavity(cav.x0, cav.x1, cav.y0, cav.y1, kick, cav.z1)
    asm.support(h, rectangle(x0, xf, y0, y1))
    style = FrontStyle(dt, hp, STEEL, DARK, handle_length=0.6 * w)
    drop_door(asm, "body", "door", x_front=xf, y0=y0, y1=y1, z0=kick, z1=h, style=style)
    racks = int(p["racks"])
    slot = (inner.z1 - inner.z0) / racks
    for i in range(racks):
        name = f"rack_{i}"
        link = asm.link(name, (0.8, 0.8, 0.82, 1.0))
        za = inner.z0 + i * slot + TRAY_CLEARANCE
        zb = za + min(0.12, 0.5 * slot)
        rx0, rx1 = inner.x0 + TRAY_CLEARANCE, inner.x1 - TRAY_CLEARANCE
        ry0, ry1 = inner.y0 + TRAY_CLEARANCE, inner.y1 - TRAY_CLEARANCE
        tray(link, rx0, rx1, ry0, ry1, za, zb, 0.008)
        link.box((rx1 - 0.008, ry0, za), (rx1, ry1, zb))
        asm.joint(
            f"{name}_slide",
            "prismatic",
            "body",
            name,
            anchor=(rx1, 0.0, za),
            axis=(1.0, 0.0, 0.0),
            lower=0.0,
            upper=0.8 * (rx1 - rx0),
        )
        asm.support(
            za + 0.008,
            rectangle(rx0 + 0.008, rx1 - 0.008, ry0 + 0.008, ry1 - 0.008),
            clearance=slot - 0.008 - TRAY_CLEARANCE,
            link=name,
            enclosed=True,
        )
    return asm


def build_wardrobe(p: Params) -> Assembly:
    asm = Assembly("wardrobe")
    body = asm.link("body", WOOD)
    w, d, h, wall = _f(p, "width"), _f(p, "depth"), _f(p, "height"), _f(p, "wall")
    dt, hp = _f(p, "door_thickness"), _f(p, "handle_protrusion")
    x0, xf = -0.5 * d, 0.5 * d - dt - hp
    y0, y1 = -0.5 * w, 0.5 * w
    zb = _base(body, "plinth", _f(p, "base_height"), x0, xf, y0, y1)
    cav = carcass(body, x0, xf, y0, y1, zb, h, wall)
    asm.support(h, rectangle(x0, xf, y0, y1))
    style = FrontStyle(dt, hp, LIGHT_WOOD, STEEL, handle_length=0.3)
    n_drawers = int(p["bottom_drawers"])
    z_doors = zb
    hang = cav
    if n_drawers:
        z_div = zb + n_drawers * DRAWER_ROW
        _board_z(body, cav, z_div, wall)
        low = Cavity(cav.x0, cav.x1, cav.y0, cav.y1, cav.z0, z_div - 0.5 * wall)
        _drawer_stack(
            asm,
            "drawer_",
            x_front=xf,
            y0=y0,
            y1=y1,
            z0=zb,
            z1=z_div - 0.5 * FRONT_GAP,
            rows=n_drawers,
            cavity=low,
            style=style,
        )
        z_doors = z_div + 0.5 * FRONT_GAP
        hang = Cavity(cav.x0, cav.x1, cav.y0, cav.y1, z_div + 0.5 * wall, cav.z1)
    n_doors = _door_count(w, int(p["doors"]))
    p["doors"] = n_doors
    gaps = door_row(
        asm,
        "body",
        "door_",
        x_front=xf,
        y0=y0,
        y1=y1,
        z0=z_doors,
        z1=h,
        count=n_doors,
        style=style,
        single_side=_side(p),
        outer_limit=FURNITURE_DOOR_LIMIT,
        handle_z=z_doors + 0.5 * (h - z_doors),
    )
    _mullions(body, gaps, xf, hang.z0, hang.z1)
    hat_z = h - min(_f(p, "hat_shelf"), 0.4 * (hang.z1 - hang.z0))
    _board_z(body, hang, hat_z, wall)
    rod_z = hat_z - 0.5 * wall - 0.06
    body.cylinder((0.5 * (hang.x0 + hang.x1), 0.0, rod_z), 0.0125, hang.y1 - hang.y0 + 2 * FUSE, "y")
    asm.support(
        hang.z0,
        rectangle(hang.x0, hang.x1 - MULLION_DEPTH, hang.y0, hang.y1),
        clearance=rod_z - 0.0125 - hang.z0,
        enclosed=True,
    )
    asm.support(
        hat_z + 0.5 * wall,
        rectangle(hang.x0, hang.x1 - MULLION_DEPTH, hang.y0, hang.y1),
        clearance=hang.z1 - hat_z - 0.5 * wall,
        enclosed=True,
    )
    return asm


def _front(**params: ParamValue) -> dict[str, ParamValue]:
    return params


_SIDES = ("left", "right")
#: Front layouts of each class: the discrete parameters that decide which doors and drawers a
#: front has (``cad.layouts.layout_variants``). A variant keeps every other parameter of its model
#: (sizes, styles), so a fit can try the model's carcass with another front.
FRONT_LAYOUTS: dict[str, tuple[dict[str, ParamValue], ...]] = {
    "cabinet": (
        *[_front(layout="doors", hinge_side=s) for s in _SIDES],
        *[_front(layout="drawers", drawer_count=n) for n in range(2, 6)],
        *[_front(layout="drawers_over_doors", hinge_side=s) for s in _SIDES],
        *[_front(layout="open_over_doors", hinge_side=s) for s in _SIDES],
    ),
    "fridge": (
        *[_front(layout=lay, hinge_side=s) for lay in ("single", "top_freezer", "bottom_freezer") for s in _SIDES],
        _front(layout="side_by_side"),
    ),
    "wardrobe": tuple(
        _front(doors=n, bottom_drawers=k, hinge_side=s)
        for n in range(1, 5) for k in range(3) for s in (_SIDES if n % 2 else _SIDES[:1])
    ),
    "oven": (_front(drawer="yes"), _front(drawer="no")),
}

SPECS: dict[str, ParamSpec] = {
    "fridge": FRIDGE_PARAMS,
    "microwave": MICROWAVE_PARAMS,
    "cabinet": CABINET_PARAMS,
    "oven": OVEN_PARAMS,
    "dishwasher": DISHWASHER_PARAMS,
    "wardrobe": WARDROBE_PARAMS,
}
BUILDERS: dict[str, Callable[[Params], Assembly]] = {
    "fridge": build_fridge,
    "microwave": build_microwave,
    "cabinet": build_cabinet,
    "oven": build_oven,
    "dishwasher": build_dishwasher,
    "wardrobe": build_wardrobe,
}
