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


# ------------------------------------------------------------------ contact2: fewer, simpler colliders
# The contact2 family's parts (tasks.CONTACT2_PART_TABLE): the contact family's parts rebuilt for a cheap
# narrow phase. Whatever is a box or a cylinder is a MuJoCo primitive; a round plug is a true cylinder in a
# hole of WALL_SIDES chamfered walls (its radial play is `clearance` towards a wall and clearance / cos(pi / 8)
# towards a corner, the same at every yaw), where the contact parts put a 16- or 24-gon prism in a hole of
# as many walls. Only the walls that carry a chamfer stay meshes.
WALL_SIDES = 8
WALL = 6.0 * MM  # wall thickness behind a hole edge (as insertion_parts)


def _hole_floor(reach: float, depth: float):
    return g.box(-reach, -reach, -depth - 4 * MM, reach, reach, -depth)


def _round_hole(radius: float, clearance: float) -> np.ndarray:
    """The WALL_SIDES-gon whose walls sit `clearance` from a cylinder of `radius` (a face normal to +x)."""
    n = WALL_SIDES
    return g.regular_polygon(n, (radius + clearance) / np.cos(np.pi / n), phase=np.pi / n)


def cylinder_peg_parts(clearance: float, depth: float, chamfer: float, length: float, radius: float = 5.0 * MM):
    """A cylindrical peg (one primitive) in a hole of WALL_SIDES chamfered walls, floor a box."""
    hole = _round_hole(radius, clearance)
    socket = g.hole_walls(hole, depth, WALL, chamfer)
    socket.append(_hole_floor(float(np.abs(hole).max()) + WALL, depth))
    return PartPieces([g.cylinder(radius, 0.0, length)], socket, gripper_pieces(radius, length))


def keyed_cylinder_parts(
    clearance: float,
    depth: float,
    chamfer: float,
    length: float,
    radius: float = 5.5 * MM,
    key_width: float = 2.4 * MM,
    key_length: float = 2.5 * MM,
):
    """A cylinder with a key on +x (two primitives, as plugs/keyed_round's outline: circle and key bar) in
    a hole of WALL_SIDES - 1 chamfered walls and a key slot cut into the +x face: two corner blocks, each
    facing that face and one side of the slot (chamfered on both), and the slot's end wall."""
    n = WALL_SIDES
    hole = g.ccw(_round_hole(radius, clearance))  # vertex 0 at +pi/n; edge n-1 (vertex n-1 -> 0) faces +x
    normals = g.edge_normals(hole)
    half = key_width / 2 + clearance  # the slot's half width
    face = radius + clearance  # x of the +x face
    end = radius + key_length + clearance  # x of the slot's end
    full_ext = WALL * np.tan(np.pi / n)
    # the walls beside the +x face stop short of the slot (their usual corner lengthening would reach into it)
    rise = (hole[1, 1] - hole[0, 1]) / np.linalg.norm(hole[1] - hole[0])
    near_slot = float(hole[0, 1] - half) / rise
    socket = []
    for i in range(n - 1):
        ext_a = min(full_ext, near_slot) if i == 0 else full_ext
        ext_b = min(full_ext, near_slot) if i + 1 == n - 1 else full_ext
        socket.append(g.wall_piece(hole[i], hole[i + 1], normals[i], ext_a, ext_b, depth, WALL, chamfer))
    top = g.chamfered_block(face, half, end + WALL, float(hole[0, 1]) + WALL, depth, chamfer, "xy")
    socket += [top, top * [1.0, -1.0, 1.0]]
    socket.append(g.chamfered_block(end, -half - WALL, end + WALL, half + WALL, depth, chamfer, "x"))
    socket.append(_hole_floor(end + WALL, depth))
    plug = [
        g.cylinder(radius, 0.0, length),
        g.box(0.0, -key_width / 2, 0.0, radius + key_length, key_width / 2, length),
    ]
    return PartPieces(plug, socket, gripper_pieces(radius + key_length, length))


def square_bore_gear_parts(clearance: float, depth: float, chamfer: float, thickness: float) -> PartPieces:
    """gear_parts' gear and neighbour with a square bore (4 chamfered pieces, their outer corners inside the
    hub) on a cylindrical shaft `clearance` narrower than the bore's half width: like gear_parts' octagonal
    pair, the shaft does not key the gear's yaw, the teeth do. Teeth, shaft, collar, base and the
    neighbour are primitives."""
    shaft_r, hub_r, tip_r, half_w = 3.0 * MM, 7.0 * MM, 9.0 * MM, 1.2 * MM
    bore = g.regular_polygon(4, (shaft_r + clearance) * np.sqrt(2.0), phase=np.pi / 4)
    ring_wall = hub_r * np.cos(np.pi / 4) - (shaft_r + clearance)  # the ring's corners stay on the hub
    rings = [p * [1, 1, -1] for p in g.hole_walls(bore, thickness, ring_wall, chamfer)]

    def teeth(phase: float, centre, z0: float, z1: float) -> list:
        out = []
        for k in range(GEAR_TEETH):
            ang = phase + 2 * np.pi * k / GEAR_TEETH
            r_mid = (hub_r - 0.5 * MM + tip_r) / 2
            mid = (centre[0] + r_mid * np.cos(ang), centre[1] + r_mid * np.sin(ang), (z0 + z1) / 2)
            out.append(g.turned_box(mid, ((tip_r - hub_r + 0.5 * MM) / 2, half_w, (z1 - z0) / 2), ang))
        return out

    gear = rings + teeth(np.pi / GEAR_TEETH, (0.0, 0.0), 0.0, thickness)
    base_z = (-depth - 4 * MM, -depth)
    fixed = [
        g.cylinder(shaft_r, -depth, 0.0),
        g.cylinder(5.0 * MM, *base_z),  # the collar the gear comes to rest on
        g.box(GEAR_CENTRE_DISTANCE - 7 * MM, -12 * MM, base_z[0], GEAR_CENTRE_DISTANCE + 12 * MM, 12 * MM, base_z[1]),
        g.cylinder(hub_r, -depth, -depth + thickness, centre=(GEAR_CENTRE_DISTANCE, 0.0)),
    ]
    fixed += teeth(np.pi, (GEAR_CENTRE_DISTANCE, 0.0), -depth, -depth + thickness)
    return PartPieces(gear, fixed, gripper_pieces(tip_r, thickness + 12 * MM))


def box_peg_parts(clearance: float, depth: float, chamfer: float, length: float) -> PartPieces:
    """insertion_parts("rect_peg") with the peg and the floor as boxes (the walls are the same)."""
    mesh = insertion_parts("rect_peg", clearance, depth, chamfer, length)
    lo, hi = mesh.plug[0].min(axis=0), mesh.plug[0].max(axis=0)
    floor = mesh.socket[-1]
    flo, fhi = floor.min(axis=0), floor.max(axis=0)
    return PartPieces([g.box(*lo, *hi)], [*mesh.socket[:-1], g.box(*flo, *fhi)], mesh.gripper)


CONTACT2_BUILDERS = {
    "cylinder_peg": cylinder_peg_parts,
    "keyed_cylinder": keyed_cylinder_parts,
    "square_bore_gear": square_bore_gear_parts,
    "box_peg": box_peg_parts,
}


def build_parts(shape: str, clearance: float, depth: float, chamfer: float, length: float) -> PartPieces:
    """The pieces of a part table row (tasks.PART_TABLE, CONTACT_PART_TABLE, CONTACT2_PART_TABLE); `length`
    is a gear's thickness."""
    if shape in CONTACT2_BUILDERS:
        return CONTACT2_BUILDERS[shape](clearance, depth, chamfer, length)
    if shape == "gear":
        return gear_parts(clearance, depth, chamfer, thickness=length)
    return insertion_parts(shape, clearance, depth, chamfer, length)
