"""2-D cross-sections and their extrusion into convex 3-D pieces (MuJoCo collides convex shapes).

Conventions: polygons are (K, 2) float arrays in metres, counter-clockwise. A plug is a union of
convex prisms standing on z = 0. A socket hole is the plug outline grown by the clearance; its
walls are one convex piece per hole edge, pushed outward from that edge, so a non-convex hole
(cross, star, L) never needs a general decomposition.
"""

from __future__ import annotations

import numpy as np


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
        a, b, n = hole[i], hole[j], normals[i]
        u = (b - a) / np.linalg.norm(b - a)
        a_ext = a - ext[i] * u
        b_ext = b + ext[j] * u
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
        pieces.append(np.array(pts, dtype=float))
    return pieces


def check_reflex_clearance(hole: np.ndarray, normals: np.ndarray, reflex: np.ndarray) -> None:
    """An edge piece at a reflex corner covers a 90-degree wedge; a sharper notch would be filled."""
    for i in np.flatnonzero(reflex):
        outside_angle = np.pi - np.arccos(np.clip(np.dot(normals[i - 1], normals[i]), -1.0, 1.0))
        if outside_angle < np.pi / 2 - 1e-6:
            raise ValueError(f"hole vertex {i} has an outside angle of {np.degrees(outside_angle):.0f} deg (< 90)")
