"""Convex hulls through MuJoCo's own mesh compiler (qhull inside MuJoCo; no scipy needed)."""

from __future__ import annotations

import numpy as np


def convex_hull(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(vertices, triangle faces) of the convex hull of `points` (M, 3)."""
    import mujoco

    pts = np.asarray(points, dtype=float)
    # MuJoCo recentres mesh vertices; compile around the centroid and shift back.
    centre = pts.mean(axis=0)
    spec = mujoco.MjSpec()
    spec.add_mesh(name="h", uservert=(pts - centre).ravel().tolist())
    spec.worldbody.add_geom(type=mujoco.mjtGeom.mjGEOM_MESH, meshname="h")
    model = spec.compile()
    start, count = model.mesh_vertadr[0], model.mesh_vertnum[0]
    fstart, fcount = model.mesh_faceadr[0], model.mesh_facenum[0]
    verts = model.mesh_vert[start : start + count].astype(float)
    faces = model.mesh_face[fstart : fstart + fcount].astype(np.int64)
    # undo the compiler's frame change (mesh_pos/mesh_quat) so vertices are in the input frame
    rot = np.zeros(9)
    mujoco.mju_quat2Mat(rot, model.mesh_quat[0])
    verts = verts @ rot.reshape(3, 3).T + model.mesh_pos[0] + centre
    return verts, faces
