"""The built-in part catalogue: convex pieces of every plug, socket and gripper, in metres.

Frames: the plug frame sits at the centre of the plug's bottom face (z up); the socket frame
sits at the centre of the hole's top opening. `scripts/make_parts.py` writes these pieces to
USD; the simulator only ever reads the USD files.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from accrue.sim import geometry as g

MM = 1e-3


@dataclass(frozen=True)
class ShapeDef:
    """A plug cross-section: its outline(s) (the hole is these grown by the clearance) and convex pieces."""

    outlines: tuple  # CCW polygons (K, 2)
    pieces: tuple  # convex CCW polygons whose union is the outline


def _cross() -> ShapeDef:
    a, b = 2.5 * MM, 8.0 * MM
    outline = np.array(
        [[b, -a], [b, a], [a, a], [a, b], [-a, b], [-a, a], [-b, a], [-b, -a], [-a, -a], [-a, -b], [a, -b], [a, -a]]
    )
    return ShapeDef((outline,), (g.rect(-b, -a, b, a), g.rect(-a, -b, a, b)))


def _star(points: int = 5, r_out: float = 9.0 * MM, r_in: float = 4.8 * MM) -> ShapeDef:
    ang = np.pi / 2 + np.pi * np.arange(2 * points) / points
    rad = np.where(np.arange(2 * points) % 2 == 0, r_out, r_in)
    outline = np.stack([rad * np.cos(ang), rad * np.sin(ang)], axis=1)
    inner = outline[1::2]
    tips = [np.array([outline[(2 * k - 1) % (2 * points)], outline[2 * k], outline[2 * k + 1]]) for k in range(points)]
    return ShapeDef((outline,), (inner, *tips))


def _convex(poly: np.ndarray) -> ShapeDef:
    poly = g.ccw(poly)
    return ShapeDef((poly,), (poly,))


def _d_shape() -> ShapeDef:
    circle = g.regular_polygon(24, 6.0 * MM)
    flat = 3.5 * MM
    keep = circle[circle[:, 0] < flat]
    y = np.sqrt((6.0 * MM) ** 2 - flat**2)
    poly = np.vstack([[[flat, -y], [flat, y]], keep[np.argsort(np.arctan2(keep[:, 1], keep[:, 0]) % (2 * np.pi))]])
    return _convex(g.ccw(poly[np.argsort(np.arctan2(poly[:, 1], poly[:, 0]))]))


def _l_shape() -> ShapeDef:
    w, lx, ly = 5.0 * MM, 15.0 * MM, 11.0 * MM
    cx, cy = 0.35 * lx, 0.35 * ly  # centre the L roughly on its area centroid
    outline = np.array([[0, 0], [lx, 0], [lx, w], [w, w], [w, ly], [0, ly]]) - [cx, cy]
    return ShapeDef((outline,), (g.rect(0, 0, lx, w) - [cx, cy], g.rect(0, w, w, ly) - [cx, cy]))


def _keyed_round() -> ShapeDef:
    r, kw, kl = 5.5 * MM, 2.4 * MM, 2.5 * MM
    circle = g.regular_polygon(24, r, phase=np.pi / 24)
    # the key sits on +x; replace the circle arc between the key's sides by the key outline
    xk = np.sqrt(r**2 - (kw / 2) ** 2)
    ang = np.arctan2(circle[:, 1], circle[:, 0])
    arc = circle[np.abs(ang) > np.arcsin(kw / 2 / r) + 1e-9]
    arc = arc[np.argsort(ang[np.abs(ang) > np.arcsin(kw / 2 / r) + 1e-9] % (2 * np.pi))]
    outline = np.vstack([[[xk, -kw / 2], [r + kl, -kw / 2], [r + kl, kw / 2], [xk, kw / 2]], arc])
    outline = g.ccw(outline)
    key = g.rect(0.0, -kw / 2, r + kl, kw / 2)
    return ShapeDef((outline,), (circle, key))


def _twin_pins() -> ShapeDef:
    pin_a = g.regular_polygon(16, 2.5 * MM) + [6.0 * MM, 0]
    pin_b = g.regular_polygon(16, 2.5 * MM) + [-6.0 * MM, 0]
    return ShapeDef((pin_a, pin_b), (pin_a, pin_b))


SHAPES = {
    "rect_peg": lambda: _convex(g.rect(-6 * MM, -4 * MM, 6 * MM, 4 * MM)),
    "round_peg": lambda: _convex(g.regular_polygon(16, 5.0 * MM)),  # 16 sides: round to within 0.1 mm
    "cross": _cross,
    "star": _star,
    "hexagon": lambda: _convex(g.regular_polygon(6, 7.0 * MM)),
    "triangle": lambda: _convex(g.regular_polygon(3, 9.0 * MM, phase=np.pi / 2)),
    "d_shape": _d_shape,
    "l_shape": _l_shape,
    "keyed_round": _keyed_round,
    "twin_pins": _twin_pins,
}


@dataclass(frozen=True)
class PartPieces:
    plug: list  # convex vertex arrays (M, 3) in the plug frame
    socket: list  # convex vertex arrays in the socket frame
    gripper: list  # visual-only boxes in the plug frame


def insertion_parts(shape: str, clearance: float, depth: float, chamfer: float, length: float) -> PartPieces:
    """A plug of `shape`, its socket (walls around the hole, floor at -depth) and its gripper."""
    sd = SHAPES[shape]()
    plug = [g.prism(p, 0.0, length) for p in sd.pieces]
    socket, reach = [], 0.0
    wall = 6.0 * MM
    for outline in sd.outlines:
        hole = g.offset_polygon(g.ccw(outline), clearance)
        socket += g.hole_walls(hole, depth, wall, chamfer)
        reach = max(reach, float(np.abs(hole).max()) + wall)
    socket.append(g.prism(g.rect(-reach, -reach, reach, reach), -depth - 4 * MM, -depth))
    extent = max(float(np.abs(o).max()) for o in sd.outlines)
    if shape == "twin_pins":  # the pins hang from a bridge that stays above the socket
        plug.append(g.prism(g.rect(-8.5 * MM, -2.5 * MM, 8.5 * MM, 2.5 * MM), depth + 3 * MM, length))
    return PartPieces(plug, socket, gripper_pieces(extent, length))


def gripper_pieces(extent: float, length: float) -> list:
    """Palm above the plug and two fingers clamping its upper end (object-specific gripper)."""
    half = extent + 1.5 * MM
    palm = g.prism(g.rect(-half, -6 * MM, half, 6 * MM), length, length + 8 * MM)
    fingers = [
        g.prism(
            g.rect(s * extent, -5 * MM, s * (extent + 3 * MM), 5 * MM)
            if s > 0
            else g.rect(s * (extent + 3 * MM), -5 * MM, s * extent, 5 * MM),
            length - 10 * MM,
            length,
        )
        for s in (1, -1)
    ]
    return [palm, *fingers]


GEAR_TEETH = 8
GEAR_CENTRE_DISTANCE = 16.5 * MM


def _gear_teeth(phase: float, hub: float, tip: float, half_width: float) -> list:
    teeth = []
    for k in range(GEAR_TEETH):
        ang = phase + 2 * np.pi * k / GEAR_TEETH
        c, s = np.cos(ang), np.sin(ang)
        local = g.rect(hub - 0.5 * MM, -half_width, tip, half_width)
        teeth.append(local @ np.array([[c, s], [-s, c]]))
    return teeth


def gear_parts(clearance: float, depth: float, chamfer: float, thickness: float) -> PartPieces:
    """Held gear (bore + 8 teeth), its shaft, and a fixed neighbour gear whose teeth it must mesh with."""
    shaft_r, hub_r, tip_r, half_w = 3.0 * MM, 7.0 * MM, 9.0 * MM, 1.2 * MM
    # an octagonal shaft keys the gear with the same 45-degree period as its teeth, in 8 wall pieces
    shaft_poly = g.regular_polygon(8, shaft_r, phase=np.pi / 8)
    bore = g.offset_polygon(shaft_poly, clearance)
    # bore walls: built like a socket hole, then flipped so the chamfer faces the gear's bottom
    rings = [p * [1, 1, -1] for p in g.hole_walls(bore, thickness, hub_r - shaft_r, chamfer)]
    teeth = [g.prism(t, 0.0, thickness) for t in _gear_teeth(np.pi / GEAR_TEETH, hub_r, tip_r, half_w)]
    shaft = [
        g.prism(shaft_poly, -depth - 4 * MM, -chamfer),
        np.vstack(
            [
                g.prism(shaft_poly, -chamfer, -chamfer)[:8],
                g.prism(shaft_poly * (shaft_r - chamfer) / shaft_r, 0.0, 0.0)[:8],
            ]
        ),
    ]
    # the gear comes to rest on a collar around the shaft; a plate carries the neighbour gear
    collar = g.prism(g.regular_polygon(8, 5.0 * MM, phase=np.pi / 8), -depth - 4 * MM, -depth)
    base = g.prism(
        g.rect(GEAR_CENTRE_DISTANCE - 7 * MM, -12 * MM, GEAR_CENTRE_DISTANCE + 12 * MM, 12 * MM),
        -depth - 4 * MM,
        -depth,
    )
    neighbour_z = (-depth, -depth + thickness)
    ncentre = np.array([GEAR_CENTRE_DISTANCE, 0.0])
    neighbour = [g.prism(g.regular_polygon(16, hub_r) + ncentre, *neighbour_z)]
    neighbour += [g.prism(t + ncentre, *neighbour_z) for t in _gear_teeth(np.pi, hub_r, tip_r, half_w)]
    return PartPieces(rings + teeth, [*shaft, collar, base, *neighbour], gripper_pieces(tip_r, thickness + 12 * MM))
