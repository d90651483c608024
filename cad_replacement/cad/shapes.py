"""Reusable furniture parts for the procedural builders: carcasses, legs, handles, doors, drawers.

All coordinates are model coordinates at the closed configuration (front = +x, left = +y, z up).
Doors and drawer fronts are *overlay* fronts: they sit in front of the carcass (x >= x_front), so
a side-hinged door opened by at most 90 degrees never enters the carcass, and one hinged at the
carcass's outer edge may open further. Where a hinge faces a neighbouring front, the gap between
the fronts is widened by the door thickness so the swinging door clears its closed neighbour.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

from cad_replacement.cad.assembly import Assembly, LinkBuilder, rectangle

RGBA = tuple[float, float, float, float]

#: Gap (m) between neighbouring fronts (doors, drawer fronts).
FRONT_GAP = 0.003
#: Clearance (m) between a drawer tray and the carcass it slides in.
TRAY_CLEARANCE = 0.006
#: How far standoffs are sunk into the panel they sit on so the union fuses them (m).
FUSE = 0.001
#: Fraction of a drawer's depth it can be pulled out.
DRAWER_TRAVEL = 0.8
#: Opening limit (rad) of a side-hinged door whose hinge faces another front or carcass part.
INNER_DOOR_LIMIT = 0.5 * np.pi
#: Opening limit (rad) of a drop-down door (oven, dishwasher).
DROP_DOOR_LIMIT = 0.5 * np.pi

WOOD: RGBA = (0.62, 0.45, 0.30, 1.0)
LIGHT_WOOD: RGBA = (0.80, 0.68, 0.50, 1.0)
WHITE: RGBA = (0.92, 0.92, 0.90, 1.0)
STEEL: RGBA = (0.70, 0.71, 0.72, 1.0)
DARK: RGBA = (0.15, 0.15, 0.16, 1.0)
FABRIC: RGBA = (0.35, 0.42, 0.55, 1.0)
GLASS: RGBA = (0.55, 0.70, 0.75, 1.0)

HingeSide = Literal["left", "right"]


@dataclass(frozen=True)
class Cavity:
    """Inner free box of a carcass (x0 = back inner face, x1 = open front)."""

    x0: float
    x1: float
    y0: float
    y1: float
    z0: float
    z1: float


def carcass(
    link: LinkBuilder,
    x0: float,
    x1: float,
    y0: float,
    y1: float,
    z0: float,
    z1: float,
    wall: float,
    back: float | None = None,
) -> Cavity:
    """Open-front box: back, two sides, bottom and top panels. Returns the inner cavity."""
    back = wall if back is None else back
    link.box((x0, y0, z0), (x0 + back, y1, z1))
    link.box((x0, y0, z0), (x1, y0 + wall, z1))
    link.box((x0, y1 - wall, z0), (x1, y1, z1))
    link.box((x0, y0, z0), (x1, y1, z0 + wall))
    link.box((x0, y0, z1 - wall), (x1, y1, z1))
    return Cavity(x0 + back, x1, y0 + wall, y1 - wall, z0 + wall, z1 - wall)


def legs(
    link: LinkBuilder,
    x0: float,
    x1: float,
    y0: float,
    y1: float,
    z0: float,
    z1: float,
    size: float,
    round_legs: bool = False,
) -> None:
    """Four legs whose outer faces touch the rectangle ``x0..x1, y0..y1``."""
    for x in (x0 + 0.5 * size, x1 - 0.5 * size):
        for y in (y0 + 0.5 * size, y1 - 0.5 * size):
            if round_legs:
                link.cylinder((x, y, 0.5 * (z0 + z1)), 0.5 * size, z1 - z0)
            else:
                link.box((x - 0.5 * size, y - 0.5 * size, z0), (x + 0.5 * size, y + 0.5 * size, z1))


def handle_bar(
    link: LinkBuilder,
    x_front: float,
    center: tuple[float, float],
    length: float,
    protrusion: float,
    along: Literal["y", "z"],
    thickness: float = 0.014,
) -> None:
    """Bar handle with two standoffs on a front whose outer face is at ``x_front``.

    ``center`` is the (y, z) of the bar centre; the bar runs along ``along`` and its outer face is
    at ``x_front + protrusion``.
    """
    if protrusion <= 1e-4:
        return  # flush/push-to-open front: no handle
    th = min(thickness, 0.5 * protrusion)
    yc, zc = center
    half = 0.5 * length
    bar_x0 = x_front + protrusion - th
    if along == "z":
        link.box((bar_x0, yc - 0.5 * th, zc - half), (x_front + protrusion, yc + 0.5 * th, zc + half))
        ends = [(yc, zc - half + th), (yc, zc + half - th)]
    else:
        link.box((bar_x0, yc - half, zc - 0.5 * th), (x_front + protrusion, yc + half, zc + 0.5 * th))
        ends = [(yc - half + th, zc), (yc + half - th, zc)]
    s = 0.4 * th
    for ey, ez in ends:
        link.box((x_front - FUSE, ey - s, ez - s), (bar_x0 + FUSE, ey + s, ez + s))


@dataclass(frozen=True)
class FrontStyle:
    """Thickness/handle/colour of doors and drawer fronts of one model."""

    thickness: float
    protrusion: float
    color: RGBA
    handle_color: RGBA = STEEL
    handle_length: float = 0.12


def hinge_pattern(count: int, single_side: HingeSide) -> list[HingeSide]:
    """Hinge side of each door, ordered from +y (left) to -y: outer hinges, pairs alternate."""
    if count == 1:
        return [single_side]
    return ["left" if i % 2 == 0 else "right" for i in range(count)]


def door_row(
    asm: Assembly,
    parent: str,
    prefix: str,
    *,
    x_front: float,
    y0: float,
    y1: float,
    z0: float,
    z1: float,
    count: int,
    style: FrontStyle,
    single_side: HingeSide = "left",
    outer_limit: float = 0.6 * np.pi,
    handle_z: float | None = None,
) -> list[tuple[float, float]]:
    """Side-hinged doors covering ``y0..y1 x z0..z1`` of the front; returns the gaps' y ranges.

    Each door is a link ``{prefix}{i}`` on a revolute joint ``{prefix}{i}_hinge`` about a vertical
    axis through its hinge edge's back corner; positive values swing it outwards (+x).
    """
    sides = hinge_pattern(count, single_side)
    gaps = []
    for i in range(count - 1):
        facing = (sides[i] == "right") + (sides[i + 1] == "left")
        gaps.append(FRONT_GAP + facing * style.thickness)
    width = (y1 - y0 - sum(gaps)) / count
    if width <= 2.0 * style.thickness:
        raise ValueError(f"{prefix}: {count} doors do not fit into {y1 - y0:.3f} m")
    gap_ranges = []
    top = y1
    zc = 0.5 * (z0 + z1) if handle_z is None else handle_z
    hl = min(style.handle_length, 0.8 * (z1 - z0))
    zc = float(np.clip(zc, z0 + 0.5 * hl + 0.01, z1 - 0.5 * hl - 0.01))
    for i, side in enumerate(sides):
        d_hi, d_lo = top, top - width
        name = f"{prefix}{i}"
        door = asm.link(name, style.color)
        door.box((x_front, d_lo, z0), (x_front + style.thickness, d_hi, z1))
        inset = min(0.05, 0.25 * width)
        handle_y = d_lo + inset if side == "left" else d_hi - inset
        handle_bar(door, x_front + style.thickness, (handle_y, zc), hl, style.protrusion, "z")
        hinge_y = d_hi if side == "left" else d_lo
        outer = (side == "left" and i == 0) or (side == "right" and i == count - 1)
        asm.joint(
            f"{name}_hinge",
            "revolute",
            parent,
            name,
            anchor=(x_front, hinge_y, z0),
            axis=(0.0, 0.0, 1.0 if side == "left" else -1.0),
            lower=0.0,
            upper=outer_limit if outer else INNER_DOOR_LIMIT,
        )
        if i < count - 1:
            gap_ranges.append((d_lo - gaps[i], d_lo))
            top = d_lo - gaps[i]
    return gap_ranges


def drop_door(
    asm: Assembly,
    parent: str,
    name: str,
    *,
    x_front: float,
    y0: float,
    y1: float,
    z0: float,
    z1: float,
    style: FrontStyle,
    window: bool = False,
) -> None:
    """Door hinged along its bottom edge (oven, dishwasher); positive values fold it down (+x)."""
    door = asm.link(name, style.color)
    door.box((x_front, y0, z0), (x_front + style.thickness, y1, z1))
    if window:
        # A slightly raised glass pane so the window shows in renders (fused into the door).
        wy, wz = 0.2 * (y1 - y0), 0.3 * (z1 - z0)
        t = x_front + style.thickness
        door.box((t - FUSE, y0 + wy, z0 + wz), (t + 0.004, y1 - wy, z1 - 0.5 * wz))
    hl = min(0.7 * (y1 - y0), max(style.handle_length, 0.5 * (y1 - y0)))
    zc = z1 - min(0.05, 0.15 * (z1 - z0))
    handle_bar(door, x_front + style.thickness, (0.5 * (y0 + y1), zc), hl, style.protrusion, "y")
    asm.joint(
        f"{name}_hinge",
        "revolute",
        parent,
        name,
        anchor=(x_front, 0.5 * (y0 + y1), z0),
        axis=(0.0, 1.0, 0.0),
        lower=0.0,
        upper=DROP_DOOR_LIMIT,
    )


def drawer(
    asm: Assembly,
    parent: str,
    name: str,
    *,
    x_front: float,
    front: tuple[float, float, float, float],
    cavity: Cavity,
    style: FrontStyle,
    wall: float = 0.012,
) -> None:
    """Drawer: overlay front ``(y0, y1, z0, z1)`` plus an open tray inside ``cavity``.

    The tray is the front's footprint shrunk to fit the cavity with ``TRAY_CLEARANCE``; it slides
    out along +x on a prismatic joint ``{name}_slide`` by up to ``DRAWER_TRAVEL`` of its depth. Its
    inner bottom is an enclosed support surface that moves with the drawer.
    """
    fy0, fy1, fz0, fz1 = front
    link = asm.link(name, style.color)
    link.box((x_front, fy0, fz0), (x_front + style.thickness, fy1, fz1))
    ty0 = max(fy0, cavity.y0) + TRAY_CLEARANCE
    ty1 = min(fy1, cavity.y1) - TRAY_CLEARANCE
    tz0 = max(fz0, cavity.z0) + TRAY_CLEARANCE
    tz1 = min(fz1, cavity.z1) - TRAY_CLEARANCE
    tx0 = cavity.x0 + TRAY_CLEARANCE
    if ty1 - ty0 < 4 * wall or tz1 - tz0 < 2 * wall or x_front - tx0 < 4 * wall:
        raise ValueError(f"drawer {name!r} does not fit its cavity")
    tray(link, tx0, x_front + FUSE, ty0, ty1, tz0, tz1, wall)
    hl = min(style.handle_length, 0.6 * (fy1 - fy0))
    handle_bar(link, x_front + style.thickness, (0.5 * (fy0 + fy1), 0.5 * (fz0 + fz1)), hl, style.protrusion, "y")
    asm.joint(
        f"{name}_slide",
        "prismatic",
        parent,
        name,
        anchor=(x_front, 0.5 * (fy0 + fy1), fz0),
        axis=(1.0, 0.0, 0.0),
        lower=0.0,
        upper=DRAWER_TRAVEL * (x_front - tx0),
    )
    asm.support(
        tz0 + wall,
        rectangle(tx0 + wall, x_front, ty0 + wall, ty1 - wall),
        clearance=tz1 - tz0 - wall,
        link=name,
        enclosed=True,
    )


def tray(link: LinkBuilder, x0: float, x1: float, y0: float, y1: float, z0: float, z1: float, wall: float) -> None:
    """Open-topped box (bottom, back, two sides; the front side is left to the caller)."""
    link.box((x0, y0, z0), (x1, y1, z0 + wall))
    link.box((x0, y0, z0), (x0 + wall, y1, z1))
    link.box((x0, y0, z0), (x1, y0 + wall, z1))
    link.box((x0, y1 - wall, z0), (x1, y1, z1))


def shelf_levels(
    asm: Assembly,
    link: LinkBuilder,
    cavity: Cavity,
    count: int,
    thickness: float,
    *,
    enclosed: bool,
    front_inset: float = 0.0,
    into_back: bool = True,
) -> None:
    """``count`` evenly spaced shelf boards inside ``cavity`` plus the support surfaces of every level.

    The cavity floor is a level too; each level's clearance is the free height to the next board.
    Boards reach ``FUSE`` into the side walls, and into the back panel when ``into_back``.
    """
    inner_h = cavity.z1 - cavity.z0
    pitch = (inner_h - count * thickness) / (count + 1)
    x1 = cavity.x1 - front_inset
    poly = rectangle(cavity.x0, x1, cavity.y0, cavity.y1)
    z = cavity.z0
    bx0 = cavity.x0 - FUSE if into_back else cavity.x0
    for i in range(count + 1):
        asm.support(z, poly, clearance=pitch, link=link.name, enclosed=enclosed)
        if i < count:
            link.box((bx0, cavity.y0 - FUSE, z + pitch), (x1, cavity.y1 + FUSE, z + pitch + thickness))
        z += pitch + thickness
