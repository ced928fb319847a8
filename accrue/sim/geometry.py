"""2-D cross-sections and their extrusion into convex 3-D pieces (MuJoCo collides convex shapes).

Conventions: polygons are (K, 2) float arrays in metres, counter-clockwise. A plug is a union of
convex prisms standing on z = 0. A socket hole is the plug outline grown by the clearance; its
walls are one convex piece per hole edge, pushed outward from that edge, so a non-convex hole
(cross, star, L) never needs a general decomposition.

A piece is either a convex vertex array or a `Primitive` (a box or a cylinder): MuJoCo collides
primitives through their exact support functions (box-box natively), which costs less per geom pair
than a mesh and, for a round part, is round where a polygon prism is not.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

PRIMITIVE_KINDS = ("box", "cylinder")


@dataclass(frozen=True)
class Primitive:
    """A box (size = half extents x, y, z) or a cylinder along its local z (size = radius, half height),
    centred at `pos` and turned by the unit quaternion `quat` (w, x, y, z), in the part frame (metres)."""

    kind: str
    size: tuple
    pos: tuple = (0.0, 0.0, 0.0)
    quat: tuple = (1.0, 0.0, 0.0, 0.0)

    def __post_init__(self) -> None:
        if self.kind not in PRIMITIVE_KINDS:
            raise ValueError(f"primitive kind must be one of {PRIMITIVE_KINDS}, got {self.kind!r}")
        need = 3 if self.kind == "box" else 2
        if len(self.size) != need or min(self.size) <= 0:
            raise ValueError(f"a {self.kind} needs {need} positive sizes, got {self.size}")
        q = np.asarray(self.quat, dtype=float)
        q = q / np.linalg.norm(q) * (1.0 if q[0] >= 0 else -1.0)  # one of q, -q: w >= 0
        object.__setattr__(self, "quat", tuple(float(v) for v in q))
        object.__setattr__(self, "size", tuple(float(v) for v in self.size))
        object.__setattr__(self, "pos", tuple(float(v) for v in self.pos))

    def rotation(self) -> np.ndarray:
        """3x3 matrix taking local coordinates to the part frame (column vectors)."""
        w, x, y, z = self.quat
        return np.array(
            [
                [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
            ]
        )

    def half_extents(self) -> np.ndarray:
        """Half extents of the local bounding box."""
        if self.kind == "box":
            return np.asarray(self.size, dtype=float)
        return np.array([self.size[0], self.size[0], self.size[1]], dtype=float)

    def corners(self) -> np.ndarray:
        """(8, 3) corners of the local bounding box in the part frame (a box's own corners)."""
        signs = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], dtype=float)
        return (signs * self.half_extents()) @ self.rotation().T + np.asarray(self.pos, dtype=float)


def box(x0: float, y0: float, z0: float, x1: float, y1: float, z1: float) -> Primitive:
    """An axis-aligned box between two corners."""
    lo, hi = np.array([x0, y0, z0], dtype=float), np.array([x1, y1, z1], dtype=float)
    return Primitive("box", tuple(map(float, (hi - lo) / 2)), tuple(map(float, (hi + lo) / 2)))


def turned_box(centre, half: tuple, yaw: float) -> Primitive:
    """A box with half extents `half`, centred at `centre` (x, y, z), turned by `yaw` about z."""
    quat = (float(np.cos(yaw / 2)), 0.0, 0.0, float(np.sin(yaw / 2)))
    return Primitive("box", tuple(map(float, half)), tuple(map(float, centre)), quat)


def cylinder(radius: float, z0: float, z1: float, centre=(0.0, 0.0)) -> Primitive:
    """An upright cylinder of `radius` between heights z0 < z1 over the point `centre` (x, y)."""
    return Primitive("cylinder", (float(radius), (z1 - z0) / 2), (float(centre[0]), float(centre[1]), (z0 + z1) / 2))


def piece_top(piece) -> float:
    """The highest point of a piece (vertex array or Primitive)."""
    pts = piece.corners() if isinstance(piece, Primitive) else np.asarray(piece)
    return float(np.max(pts[:, 2]))


def regular_polygon(n: int, radius: float, phase: float = 0.0) -> np.ndarray:
    ang = phase + 2 * np.pi * np.arange(n) / n
    return np.stack([radius * np.cos(ang), radius * np.sin(ang)], axis=1)


def rect(x0: float, y0: float, x1: float, y1: float) -> np.ndarray:
    return np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]], dtype=float)


def signed_area(poly: np.ndarray) -> float:
    x, y = poly[:, 0], poly[:, 1]
    return 0.5 * float(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y))


def ccw(poly: np.ndarray) -> np.ndarray:
    poly = np.asarray(poly, dtype=float)
    return poly if signed_area(poly) > 0 else poly[::-1].copy()


def edge_normals(poly: np.ndarray) -> np.ndarray:
    """Outward unit normals of a CCW polygon's edges (edge i runs from vertex i to i+1)."""
    d = np.roll(poly, -1, axis=0) - poly
    n = np.stack([d[:, 1], -d[:, 0]], axis=1)
    return n / np.linalg.norm(n, axis=1, keepdims=True)


def reflex_vertices(poly: np.ndarray) -> np.ndarray:
    """Boolean mask of vertices whose interior angle exceeds 180 degrees (CCW polygon)."""
    prev = poly - np.roll(poly, 1, axis=0)
    nxt = np.roll(poly, -1, axis=0) - poly
    cross = prev[:, 0] * nxt[:, 1] - prev[:, 1] * nxt[:, 0]
    return cross < 0


def offset_polygon(poly: np.ndarray, dist: float) -> np.ndarray:
    """Mitred offset of a CCW polygon: every edge moves `dist` along its outward normal."""
    n = edge_normals(poly)
    c = np.einsum("ij,ij->i", n, poly) + dist
    out = np.empty_like(poly)
    for i in range(len(poly)):
        a = np.array([n[i - 1], n[i]])
        b = np.array([c[i - 1], c[i]])
        out[i] = np.linalg.solve(a, b)
    return out


def prism(poly: np.ndarray, z0: float, z1: float) -> np.ndarray:
    """Vertices (2K, 3) of a vertical prism; MuJoCo takes the convex hull."""
    k = len(poly)
    return np.concatenate([np.column_stack([poly, np.full(k, z0)]), np.column_stack([poly, np.full(k, z1)])])


def hole_walls(hole: np.ndarray, depth: float, thickness: float, chamfer: float) -> list[np.ndarray]:
    """Convex wall pieces around a CCW hole outline, top at z = 0, bottom at z = -depth.

    Each edge's piece extends past convex corners (so no wedge-shaped gap opens there) and
    stops at reflex corners (so it never reaches into the hole). A chamfer of width `chamfer`
    bevels the top inner edge, which lets a compliant plug slide into the hole.
    """
    hole = ccw(hole)
    normals = edge_normals(hole)
    reflex = reflex_vertices(hole)
    check_reflex_clearance(hole, normals, reflex)
    pieces = []
    # at a convex corner, extending by thickness * tan(turn / 2) makes neighbours meet at the mitre
    turn = np.arccos(np.clip(np.einsum("ij,ij->i", np.roll(normals, 1, axis=0), normals), -1.0, 1.0))
    ext = np.where(reflex, 0.0, thickness * np.minimum(np.tan(turn / 2), 2.0))
    for i in range(len(hole)):
        j = (i + 1) % len(hole)
        pieces.append(wall_piece(hole[i], hole[j], normals[i], ext[i], ext[j], depth, thickness, chamfer))
    return pieces


def wall_piece(a, b, n, ext_a: float, ext_b: float, depth: float, thickness: float, chamfer: float) -> np.ndarray:
    """The convex wall behind the hole edge a -> b (outward normal n), lengthened by ext_a before a and
    ext_b past b, `thickness` thick, top at z = 0 with its inner top edge chamfered, bottom at -depth."""
    a, b, n = (np.asarray(v, dtype=float) for v in (a, b, n))
    u = (b - a) / np.linalg.norm(b - a)
    a_ext = a - ext_a * u
    b_ext = b + ext_b * u
    c = min(chamfer, 0.9 * thickness, 0.9 * depth)
    pts = [
        (*a_ext, -depth),
        (*b_ext, -depth),
        (*(a_ext + thickness * n), -depth),
        (*(b_ext + thickness * n), -depth),
        (*a_ext, -c),
        (*b_ext, -c),
        (*(a_ext + c * n), 0.0),
        (*(b_ext + c * n), 0.0),
        (*(a_ext + thickness * n), 0.0),
        (*(b_ext + thickness * n), 0.0),
    ]
    return np.array(pts, dtype=float)


def chamfered_block(x0: float, y0: float, x1: float, y1: float, depth: float, chamfer: float, edges: str) -> np.ndarray:
    """Vertices of the block [x0, x1] x [y0, y1] x [-depth, 0] whose top edges along x = x0 (edges has
    "x") and y = y0 (edges has "y") are chamfered: a wall piece that can face a hole on two sides that
    meet at a right angle (a key slot's side and the face it is cut into), convex because the material
    there is the intersection of two half-planes."""
    c = min(chamfer, 0.9 * (x1 - x0), 0.9 * (y1 - y0), 0.9 * depth)
    cx = x0 + c if "x" in edges else x0
    cy = y0 + c if "y" in edges else y0
    pts = [(x, y, -depth) for x in (x0, x1) for y in (y0, y1)]
    pts += [(x, y, 0.0) for x in (cx, x1) for y in (cy, y1)]
    pts += [(x, y, -c) for x in (x0, x1) for y in (y0, y1)]
    return np.array(pts, dtype=float)


def check_reflex_clearance(hole: np.ndarray, normals: np.ndarray, reflex: np.ndarray) -> None:
    """An edge piece at a reflex corner covers a 90-degree wedge; a sharper notch would be filled."""
    for i in np.flatnonzero(reflex):
        outside_angle = np.pi - np.arccos(np.clip(np.dot(normals[i - 1], normals[i]), -1.0, 1.0))
        if outside_angle < np.pi / 2 - 1e-6:
            raise ValueError(f"hole vertex {i} has an outside angle of {np.degrees(outside_angle):.0f} deg (< 90)")


def quat_from_matrix(rot) -> tuple:
    """Unit quaternion (w, x, y, z), w >= 0, of a rotation matrix (column vectors: v' = rot @ v)."""
    m = np.asarray(rot, dtype=float)
    trace = m[0, 0] + m[1, 1] + m[2, 2]
    if trace > 0:
        s = 2.0 * np.sqrt(trace + 1.0)
        q = [0.25 * s, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s]
    else:
        i = int(np.argmax(np.diag(m)))
        j, k = (i + 1) % 3, (i + 2) % 3
        s = 2.0 * np.sqrt(1.0 + m[i, i] - m[j, j] - m[k, k])
        q = [0.0] * 4
        q[0] = (m[k, j] - m[j, k]) / s
        q[1 + i] = 0.25 * s
        q[1 + j] = (m[j, i] + m[i, j]) / s
        q[1 + k] = (m[k, i] + m[i, k]) / s
    q = np.asarray(q) / np.linalg.norm(q)
    return tuple(float(v) for v in (q if q[0] >= 0 else -q))
