"""Part geometry in USD: write convex pieces, read any mesh part back as convex pieces (metres, Z up).

Reading honours metersPerUnit and upAxis, walks instance proxies (instanced references hide
meshes from a plain traversal), and splits non-convex meshes with coacd. A `Cube` or `Cylinder`
prim with `PhysicsCollisionAPI` is read as a `geometry.Primitive` (MuJoCo collides it as a box or a
cylinder); one without that API is visual and ignored, as before.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from accrue.errors import AccrueError
from accrue.sim.geometry import Primitive, quat_from_matrix
from accrue.sim.hull import convex_hull

# row-vector map from a Y-up file's axes to Z up: the file's +y becomes +z
_Y_UP_TO_Z_UP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])
# a USD cylinder's axis -> the order of local axes that puts it on MuJoCo's cylinder axis (z), right-handed
_CYLINDER_AXES = {"X": (1, 2, 0), "Y": (2, 0, 1), "Z": (0, 1, 2)}


def _nearest(verts: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """Index of the input point each (float32-rounded) hull vertex came from."""
    pts = np.asarray(pts, dtype=float)
    return np.argmin(((verts[:, None, :] - pts[None, :, :]) ** 2).sum(-1), axis=1)


def write_part(path: Path, pieces: list[np.ndarray], name: str = "Part") -> None:
    """One Xform holding one convex Mesh per piece, each flagged as a convex-hull collider."""
    from pxr import Gf, Sdf, Usd, UsdGeom, UsdPhysics, Vt

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.unlink(missing_ok=True)
    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.z)
    root = UsdGeom.Xform.Define(stage, Sdf.Path(f"/{name}"))
    stage.SetDefaultPrim(root.GetPrim())
    for i, pts in enumerate(pieces):
        if isinstance(pts, Primitive):
            _write_primitive(stage, root.GetPath().AppendChild(f"piece_{i:03d}"), pts)
            continue
        verts, faces = convex_hull(np.asarray(pts, dtype=float))
        used, faces = np.unique(faces, return_inverse=True)
        verts, faces = np.asarray(pts, dtype=float)[_nearest(verts[used], pts)], faces.reshape(-1, 3)
        mesh = UsdGeom.Mesh.Define(stage, root.GetPath().AppendChild(f"piece_{i:03d}"))
        mesh.CreatePointsAttr(Vt.Vec3fArray([Gf.Vec3f(*map(float, p)) for p in verts]))
        mesh.CreateFaceVertexCountsAttr(Vt.IntArray([3] * len(faces)))
        mesh.CreateFaceVertexIndicesAttr(Vt.IntArray([int(v) for v in faces.ravel()]))
        UsdPhysics.CollisionAPI.Apply(mesh.GetPrim())
        UsdPhysics.MeshCollisionAPI.Apply(mesh.GetPrim()).CreateApproximationAttr("convexHull")
    stage.GetRootLayer().Save()


def _write_primitive(stage, path, piece: Primitive) -> None:
    """A Cube (size 2, scaled by the half extents) or a Z Cylinder, placed by translate and orient ops."""
    from pxr import Gf, UsdGeom, UsdPhysics

    double = UsdGeom.XformOp.PrecisionDouble
    if piece.kind == "box":
        prim = UsdGeom.Cube.Define(stage, path)
        prim.CreateSizeAttr(2.0)
        prim.CreateExtentAttr([Gf.Vec3f(-1.0, -1.0, -1.0), Gf.Vec3f(1.0, 1.0, 1.0)])
    else:
        radius, half = piece.size
        prim = UsdGeom.Cylinder.Define(stage, path)
        prim.CreateRadiusAttr(float(radius))
        prim.CreateHeightAttr(float(2 * half))
        prim.CreateAxisAttr(UsdGeom.Tokens.z)
        prim.CreateExtentAttr([Gf.Vec3f(-radius, -radius, -half), Gf.Vec3f(radius, radius, half)])
    prim.AddTranslateOp(double).Set(Gf.Vec3d(*map(float, piece.pos)))
    prim.AddOrientOp(double).Set(Gf.Quatd(*map(float, piece.quat)))
    if piece.kind == "box":
        prim.AddScaleOp(double).Set(Gf.Vec3d(*map(float, piece.size)))
    UsdPhysics.CollisionAPI.Apply(prim.GetPrim())


def _read_primitive(prim, matrix: np.ndarray, scale: float, y_up: bool, path: Path) -> Primitive:
    """A Cube or Cylinder prim as a Primitive in metres, Z up (`matrix`: its row-vector local-to-world)."""
    from pxr import UsdGeom

    rows, centre = matrix[:3, :3], matrix[3, :3]
    stretch = np.linalg.norm(rows, axis=1)
    axes = rows / stretch[:, None]  # row i: where the prim's local axis i points
    if not np.allclose(axes @ axes.T, np.eye(3), atol=1e-6) or np.linalg.det(axes) < 0:
        raise AccrueError(f"USD file {path}: {prim.GetPath()} is sheared or mirrored (not a box or a cylinder)")
    if y_up:
        axes, centre = axes @ _Y_UP_TO_Z_UP, centre @ _Y_UP_TO_Z_UP
    if prim.IsA(UsdGeom.Cube):
        half = 0.5 * float(UsdGeom.Cube(prim).GetSizeAttr().Get()) * stretch * scale
        return Primitive("box", tuple(map(float, half)), tuple(map(float, centre * scale)), quat_from_matrix(axes.T))
    cyl = UsdGeom.Cylinder(prim)
    order = _CYLINDER_AXES[str(cyl.GetAxisAttr().Get())]
    radial = stretch[list(order[:2])]
    if not np.isclose(radial[0], radial[1], rtol=1e-6):
        raise AccrueError(f"USD file {path}: cylinder {prim.GetPath()} is scaled unevenly across its axis")
    radius = float(cyl.GetRadiusAttr().Get()) * radial[0] * scale
    half = 0.5 * float(cyl.GetHeightAttr().Get()) * stretch[order[2]] * scale
    return Primitive(
        "cylinder", (radius, half), tuple(map(float, centre * scale)), quat_from_matrix(axes[list(order)].T)
    )


def _triangulate(counts: np.ndarray, indices: np.ndarray) -> np.ndarray:
    tris, start = [], 0
    for c in counts:
        face = indices[start : start + c]
        tris += [(face[0], face[k], face[k + 1]) for k in range(1, c - 1)]
        start += c
    return np.asarray(tris, dtype=np.int64).reshape(-1, 3)


def _is_convex(vertices: np.ndarray, faces: np.ndarray) -> bool:
    import trimesh

    mesh = trimesh.Trimesh(vertices, faces, process=True)
    hv, hf = convex_hull(vertices)
    hull_volume = trimesh.Trimesh(hv, hf, process=True).volume
    if not mesh.is_watertight or hull_volume <= 0:
        return False
    return abs(mesh.volume) >= 0.985 * abs(hull_volume)


def _decompose(vertices: np.ndarray, faces: np.ndarray, threshold: float) -> list[np.ndarray]:
    import coacd

    coacd.set_log_level("error")
    parts = coacd.run_coacd(coacd.Mesh(vertices, faces), threshold=threshold, seed=0)
    return [np.asarray(v, dtype=float) for v, _f in parts]


def read_part(path: Path, *, decompose_threshold: float = 0.04) -> list:
    """Convex pieces of a USD file, in metres, Z up: a vertex array per mesh (convex piece) and a Primitive per
    Cube or Cylinder that carries PhysicsCollisionAPI, in the file's order."""
    path = Path(path)
    if not path.is_file():
        raise AccrueError(f"USD part file not found: {path}")
    try:
        from pxr import Usd, UsdGeom, UsdPhysics

        stage = Usd.Stage.Open(str(path))
    except Exception as exc:  # pxr raises Tf errors of several types for a malformed layer
        raise AccrueError(f"cannot read USD file {path}: {str(exc).splitlines()[0] if str(exc) else exc}") from None
    if stage is None:
        raise AccrueError(f"cannot read USD file {path}")
    scale = UsdGeom.GetStageMetersPerUnit(stage)
    y_up = UsdGeom.GetStageUpAxis(stage) == UsdGeom.Tokens.y
    cache = UsdGeom.XformCache()
    pieces = []
    for prim in Usd.PrimRange(stage.GetPseudoRoot(), Usd.TraverseInstanceProxies()):
        if (prim.IsA(UsdGeom.Cube) or prim.IsA(UsdGeom.Cylinder)) and prim.HasAPI(UsdPhysics.CollisionAPI):
            matrix = np.asarray(cache.GetLocalToWorldTransform(prim), dtype=float)
            pieces.append(_read_primitive(prim, matrix, scale, y_up, path))
            continue
        if not prim.IsA(UsdGeom.Mesh):
            continue
        mesh = UsdGeom.Mesh(prim)
        pts, counts, idx = (
            mesh.GetPointsAttr().Get(),
            mesh.GetFaceVertexCountsAttr().Get(),
            mesh.GetFaceVertexIndicesAttr().Get(),
        )
        if pts is None or len(pts) < 4:
            continue
        # row-vector convention: p_world = [p, 1] @ M
        m = np.asarray(cache.GetLocalToWorldTransform(prim), dtype=float)
        v = np.asarray(pts, dtype=float) @ m[:3, :3] + m[3, :3]
        v *= scale
        if y_up:  # rotate +90 deg about x so that the file's +y becomes +z
            v = np.column_stack([v[:, 0], -v[:, 2], v[:, 1]])
        if np.linalg.matrix_rank(v - v.mean(axis=0), tol=1e-9) < 3:
            raise AccrueError(f"USD file {path}: mesh {prim.GetPath()} is flat or degenerate (no volume)")
        approx = None
        if prim.HasAPI(UsdPhysics.MeshCollisionAPI):
            approx = UsdPhysics.MeshCollisionAPI(prim).GetApproximationAttr().Get()
        faces = _triangulate(np.asarray(counts), np.asarray(idx)) if counts is not None and idx is not None else None
        if approx == "convexHull" or faces is None or len(faces) == 0 or _is_convex(v, faces):
            pieces.append(v)
        else:
            pieces += _decompose(v, faces, decompose_threshold)
    if not pieces:
        raise AccrueError(f"USD file {path} contains no mesh geometry (nor a Cube or Cylinder collider)")
    return pieces
