"""Procedural small rigid objects: monitor, bag, box, cup, bottle, book.

Same contract as ``builders_furniture``: the final parameter dict's ``(depth, width, height)`` are
the model's exact overall extents (derived keys are written back into the dict).
"""

from __future__ import annotations

from collections.abc import Callable

from cad_replacement.cad.assembly import Assembly, LinkBuilder, rectangle
from cad_replacement.cad.params import Choice, ParamSpec, ParamValue, Uniform
from cad_replacement.cad.shapes import DARK, FABRIC, FUSE, GLASS, LIGHT_WOOD, WHITE

Params = dict[str, ParamValue]

MONITOR_PARAMS: ParamSpec = {
    "width": Uniform(0.45, 0.75),  # screen width (y)
    "aspect": Uniform(0.50, 0.65),  # screen height / width
    "panel_thickness": Uniform(0.015, 0.05),
    "stand": Choice(("pedestal", "feet")),
    "base_depth": Uniform(0.14, 0.25),  # = overall depth
    "screen_elevation": Uniform(0.05, 0.15),
    "bezel": Uniform(0.005, 0.02),
}
BAG_PARAMS: ParamSpec = {
    "style": Choice(("handbag", "backpack", "suitcase")),
    "width": Uniform(0.25, 0.50),
    "depth": Uniform(0.10, 0.28),
    "height": Uniform(0.20, 0.60),  # including the handle
    "handle_height": Uniform(0.04, 0.12),
}
BOX_PARAMS: ParamSpec = {
    "width": Uniform(0.12, 0.60),
    "depth": Uniform(0.12, 0.50),
    "height": Uniform(0.08, 0.50),
    "lid": Choice(("none", "lid")),
    "lid_height": Uniform(0.02, 0.06),
}
CUP_PARAMS: ParamSpec = {
    "width": Uniform(0.065, 0.10),  # rim diameter
    "height": Uniform(0.07, 0.14),
    "wall": Uniform(0.003, 0.006),
    "bottom": Uniform(0.005, 0.012),
    "handle": Choice(("yes", "no"), (0.7, 0.3)),
    "handle_reach": Uniform(0.02, 0.035),  # depth = width + reach with a handle (handle towards +x)
}
BOTTLE_PARAMS: ParamSpec = {
    "shape": Choice(("round", "square"), (0.8, 0.2)),
    "width": Uniform(0.05, 0.10),
    "height": Uniform(0.18, 0.35),
    "neck_diameter": Uniform(0.02, 0.035),
    "neck_fraction": Uniform(0.12, 0.25),
    "shoulder_fraction": Uniform(0.05, 0.12),
}
BOOK_PARAMS: ParamSpec = {
    "orientation": Choice(("lying", "standing")),  # standing: spine towards +x, as on a shelf
    "page_height": Uniform(0.17, 0.30),
    "page_width": Uniform(0.11, 0.22),
    "thickness": Uniform(0.008, 0.06),
    "cover": Uniform(0.001, 0.003),
}

#: Cap height of a bottle (m).
BOTTLE_CAP = 0.02
#: Inset of a book's page block from the cover edges (m).
PAGE_INSET = 0.003


def _f(p: Params, key: str) -> float:
    return float(p[key])


def build_monitor(p: Params) -> Assembly:
    asm = Assembly("monitor")
    body = asm.link("body", DARK)
    w = _f(p, "width")
    sh = w * _f(p, "aspect")
    pt = _f(p, "panel_thickness")
    bd = max(_f(p, "base_depth"), pt + 0.08)
    elev = _f(p, "screen_elevation")
    bezel = min(_f(p, "bezel"), 0.1 * sh)
    p.update(depth=bd, height=elev + sh)
    x_front = 0.5 * bd - 0.02
    xp0 = x_front - pt
    body.box((xp0, -0.5 * w, elev), (x_front, 0.5 * w, elev + sh))
    screen = asm.link("screen", GLASS)
    screen.box((x_front, -0.5 * w + bezel, elev + bezel), (x_front + 0.002, 0.5 * w - bezel, elev + sh - bezel))
    asm.joint("screen_fixed", "fixed", "body", "screen", anchor=(x_front, 0.0, elev))
    neck = 0.05
    body.box((xp0 - 0.03, -0.5 * neck, 0.0), (xp0 + FUSE, 0.5 * neck, elev + 0.5 * sh))
    if p["stand"] == "pedestal":
        bw = min(0.6 * w, 0.3)
        body.box((-0.5 * bd, -0.5 * bw, 0.0), (0.5 * bd, 0.5 * bw, 0.015))
    else:
        for y in (-0.35 * w, 0.35 * w):
            body.box((-0.5 * bd, y - 0.015, 0.0), (0.5 * bd, y + 0.015, 0.015))
        body.box((xp0 - 0.03, -0.35 * w, 0.0), (xp0 + FUSE, 0.35 * w, 0.015))
    return asm


def build_bag(p: Params) -> Assembly:
    asm = Assembly("bag")
    style = p["style"]
    body = asm.link("body", FABRIC if style != "suitcase" else DARK)
    w, d, h = _f(p, "width"), _f(p, "depth"), _f(p, "height")
    hh = min(_f(p, "handle_height"), 0.4 * h)
    body_h = h - hh
    x0, x1, y0, y1 = -0.5 * d, 0.5 * d, -0.5 * w, 0.5 * w
    z0 = 0.0
    if style == "suitcase":
        r = min(0.025, 0.1 * body_h)
        for x in (x0 + r, x1 - r):
            body.cylinder((x, 0.0, r), r, w - 0.04, "y")
        z0 = r
    bx1 = x1
    if style == "backpack":
        pocket = 0.3 * d
        bx1 = x1 - pocket
        body.box((bx1 - FUSE, y0 + 0.15 * w, z0 + 0.1 * body_h), (x1, y1 - 0.15 * w, z0 + 0.55 * body_h))
    body.box((x0, y0, z0), (bx1, y1, body_h))
    xc = 0.5 * (x0 + bx1)
    t = 0.015
    span = 0.25 * w if style != "handbag" else 0.35 * w
    for y in (-span, span - t):
        body.box((xc - 0.5 * t, y, body_h - FUSE), (xc + 0.5 * t, y + t, h))
    body.box((xc - 0.5 * t, -span, h - t), (xc + 0.5 * t, span, h))
    return asm


def build_box(p: Params) -> Assembly:
    asm = Assembly("box")
    body = asm.link("body", LIGHT_WOOD)
    w, d, h = _f(p, "width"), _f(p, "depth"), _f(p, "height")
    if p["lid"] == "lid":
        lid_h = min(_f(p, "lid_height"), 0.4 * h)
        over = min(0.005, 0.05 * min(w, d))
        body.box((-0.5 * d + over, -0.5 * w + over, 0.0), (0.5 * d - over, 0.5 * w - over, h - lid_h + FUSE))
        body.box((-0.5 * d, -0.5 * w, h - lid_h), (0.5 * d, 0.5 * w, h))
    else:
        body.box((-0.5 * d, -0.5 * w, 0.0), (0.5 * d, 0.5 * w, h))
    asm.support(h, rectangle(-0.5 * d, 0.5 * d, -0.5 * w, 0.5 * w))
    return asm


def build_cup(p: Params) -> Assembly:
    asm = Assembly("cup")
    body = asm.link("body", WHITE)
    w, h = _f(p, "width"), _f(p, "height")
    r = 0.5 * w
    wall = min(_f(p, "wall"), 0.2 * r)
    bottom = min(_f(p, "bottom"), 0.3 * h)
    body.cylinder((0.0, 0.0, 0.5 * h), r, h)
    body.cylinder((0.0, 0.0, bottom + 0.5 * h), r - wall, h, cut=True)
    reach = 0.0
    if p["handle"] == "yes":
        reach = _f(p, "handle_reach")
        t, half_w = 0.008, 0.005
        za, zb = 0.25 * h, 0.8 * h
        x_in = r - 0.5 * wall
        body.box((r + reach - t, -half_w, za), (r + reach, half_w, zb))
        body.box((x_in, -half_w, za), (r + reach, half_w, za + t))
        body.box((x_in, -half_w, zb - t), (r + reach, half_w, zb))
    p["depth"] = w + reach
    return asm


def build_bottle(p: Params) -> Assembly:
    asm = Assembly("bottle")
    body = asm.link("body", GLASS)
    w, h = _f(p, "width"), _f(p, "height")
    r = 0.5 * w
    rn = min(0.5 * _f(p, "neck_diameter"), 0.6 * r)
    neck_h = _f(p, "neck_fraction") * h
    shoulder_h = _f(p, "shoulder_fraction") * h
    body_h = h - neck_h - shoulder_h
    p["depth"] = w
    if p["shape"] == "square":
        body.box((-r, -r, 0.0), (r, r, body_h))
        rs = 0.5 * (r + rn)
        body.box((-rs, -rs, body_h - FUSE), (rs, rs, body_h + shoulder_h))
    else:
        body.cylinder((0.0, 0.0, 0.5 * body_h), r, body_h)
        body.cylinder((0.0, 0.0, body_h + 0.5 * shoulder_h - 0.5 * FUSE), 0.5 * (r + rn), shoulder_h + FUSE)
    z_neck = body_h + shoulder_h - FUSE
    cap = min(BOTTLE_CAP, 0.5 * neck_h)
    body.cylinder((0.0, 0.0, 0.5 * (z_neck + h - cap)), rn, h - cap - z_neck)
    lid = asm.link("cap", DARK)
    lid.cylinder((0.0, 0.0, h - 0.5 * cap), min(rn + 0.002, r), cap)
    asm.joint("cap_fixed", "fixed", "body", "cap", anchor=(0.0, 0.0, h - cap))
    return asm


def build_book(p: Params) -> Assembly:
    asm = Assembly("book")
    body = asm.link("body", FABRIC)
    ph, pw, t, c = _f(p, "page_height"), _f(p, "page_width"), _f(p, "thickness"), _f(p, "cover")
    c = min(c, 0.2 * t)
    standing = p["orientation"] == "standing"

    def emit(link: LinkBuilder, lo: tuple[float, float, float], hi: tuple[float, float, float]) -> None:
        """Boxes are authored lying (spine at -x, pages along y, thickness along z)."""
        if standing:  # spine to +x, thickness along y, page height along z
            link.box((-hi[0], lo[2] - 0.5 * t, lo[1] + 0.5 * ph), (-lo[0], hi[2] - 0.5 * t, hi[1] + 0.5 * ph))
        else:
            link.box(lo, hi)

    x0, x1, y0, y1 = -0.5 * pw, 0.5 * pw, -0.5 * ph, 0.5 * ph
    emit(body, (x0, y0, 0.0), (x1, y1, c))
    emit(body, (x0, y0, t - c), (x1, y1, t))
    emit(body, (x0, y0, 0.0), (x0 + c, y1, t))
    emit(body, (x0 + c - FUSE, y0 + PAGE_INSET, c - FUSE), (x1 - PAGE_INSET, y1 - PAGE_INSET, t - c + FUSE))
    if standing:
        p.update(depth=pw, width=t, height=ph)
    else:
        p.update(depth=pw, width=ph, height=t)
        asm.support(t, rectangle(x0, x1, y0, y1))
    return asm


SPECS: dict[str, ParamSpec] = {
    "monitor": MONITOR_PARAMS,
    "bag": BAG_PARAMS,
    "box": BOX_PARAMS,
    "cup": CUP_PARAMS,
    "bottle": BOTTLE_PARAMS,
    "book": BOOK_PARAMS,
}
BUILDERS: dict[str, Callable[[Params], Assembly]] = {
    "monitor": build_monitor,
    "bag": build_bag,
    "box": build_box,
    "cup": build_cup,
    "bottle": build_bottle,
    "book": build_book,
}
