"""USD parts: committed assets match the generator, user parts round-trip into runnable tasks, bad files fail cleanly."""

from pathlib import Path

import numpy as np
import pytest

from accrue.errors import AccrueError
from accrue.sim import get_task, list_tasks, load_task_yaml, make_vec_env, register_usd_task
from accrue.sim.geometry import Primitive
from accrue.sim.tasks import MM
from accrue.sim.usd_parts import read_part, write_part


def test_task_catalogue():
    assert list_tasks("nist") == ["nist/gear", "nist/rect_peg", "nist/round_peg"]
    plugs = list_tasks("plugs")
    assert len(plugs) >= 8
    for tid in list_tasks():
        spec = get_task(tid)
        assert spec.plug_usd.is_file() and spec.socket_usd.is_file() and spec.instruction
    with pytest.raises(AccrueError) as e:
        get_task("nist/nut")
    assert "\n" not in str(e.value)


def test_committed_assets_match_the_generator(tmp_path):
    import importlib.util

    spec = importlib.util.spec_from_file_location("make_parts", Path(__file__).parents[1] / "scripts" / "make_parts.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    for path in mod.build_all(tmp_path):
        rel = path.relative_to(tmp_path)
        fresh, committed = (
            read_part(path),
            read_part(get_task(f"{rel.parts[0]}/{rel.parts[1]}").plug_usd.parent / rel.name),
        )
        assert len(fresh) == len(committed)
        for a, b in zip(fresh, committed):
            if isinstance(a, Primitive):  # contact2's boxes and cylinders
                assert isinstance(b, Primitive) and a.kind == b.kind
                assert np.allclose(a.size + a.pos + a.quat, b.size + b.pos + b.quat, atol=1e-9)
            else:
                assert np.allclose(a, b, atol=1e-9)


def _author_instanced_cm_yup(path, pieces_m, name):
    """Author like a CAD/Isaac export: centimetres, Y up, geometry behind an instanceable reference."""
    from pxr import Gf, Usd, UsdGeom, Vt

    proto_path = path.with_name(path.stem + "_proto.usda")
    proto = Usd.Stage.CreateNew(str(proto_path))
    root = UsdGeom.Xform.Define(proto, "/Proto")
    proto.SetDefaultPrim(root.GetPrim())
    for i, pts in enumerate(pieces_m):
        from accrue.sim.hull import convex_hull

        v, f = convex_hull(pts)
        v_yup = np.column_stack([v[:, 0], v[:, 2], -v[:, 1]]) * 100.0  # z-up m -> y-up cm
        mesh = UsdGeom.Mesh.Define(proto, f"/Proto/piece_{i}")
        mesh.CreatePointsAttr(Vt.Vec3fArray([Gf.Vec3f(*map(float, p)) for p in v_yup]))
        mesh.CreateFaceVertexCountsAttr(Vt.IntArray([3] * len(f)))
        mesh.CreateFaceVertexIndicesAttr(Vt.IntArray([int(x) for x in f.ravel()]))
    proto.GetRootLayer().Save()
    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.SetStageMetersPerUnit(stage, 0.01)
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    top = UsdGeom.Xform.Define(stage, f"/{name}")
    stage.SetDefaultPrim(top.GetPrim())
    inst = UsdGeom.Xform.Define(stage, f"/{name}/geo").GetPrim()
    inst.GetReferences().AddReference(proto_path.name)
    inst.SetInstanceable(True)
    stage.GetRootLayer().Save()
    assert len(list(stage.Traverse())) < len(list(Usd.PrimRange(stage.GetPseudoRoot(), Usd.TraverseInstanceProxies())))


def test_user_usd_part_round_trips_into_a_runnable_task(tmp_path):
    from accrue.sim.part_shapes import insertion_parts

    parts = insertion_parts("hexagon", 0.3 * MM, 10 * MM, 0.7 * MM, 24 * MM)
    _author_instanced_cm_yup(tmp_path / "plug.usda", parts.plug, "Plug")
    _author_instanced_cm_yup(tmp_path / "socket.usda", parts.socket, "Socket")
    back = read_part(tmp_path / "plug.usda")
    assert len(back) == 1
    assert np.allclose(sorted(back[0][:, 2]), sorted(np.unique(parts.plug[0][:, 2].round(6)).repeat(6)), atol=1e-6)
    spec = register_usd_task(
        "mine/hex",
        tmp_path / "plug.usda",
        tmp_path / "socket.usda",
        depth=10 * MM,
        yaw_symmetry=6,
        clearance=0.3 * MM,  # the parts' own: a task left registered keeps the geometry descriptor in range
        chamfer=0.7 * MM,
        replace=True,
    )
    assert "mine/hex" in list_tasks()
    from accrue.sim import make_expert

    env, expert = make_vec_env(spec.task_id, num_envs=6, seed=0), make_expert(spec.task_id, 1.0, seed=0)
    obs, won = env.reset(), np.zeros(6, bool)
    for _ in range(spec.max_steps):
        res = env.step(expert.act(obs["state"]))
        obs, won = res.obs, won | res.success
    assert won.mean() >= 0.5


def _l_prism():
    """A watertight L-shaped prism as one triangle mesh (a non-convex solid)."""
    poly = np.array([[0, 0], [0.03, 0], [0.03, 0.01], [0.01, 0.01], [0.01, 0.03], [0, 0.03]])
    verts = np.vstack([np.column_stack([poly, np.zeros(6)]), np.column_stack([poly, np.full(6, 0.01)])])
    fan = [(3, 4, 5), (3, 5, 0), (3, 0, 1), (3, 1, 2)]  # the reflex corner sees every other vertex
    faces = [(a, c, b) for a, b, c in fan] + [(a + 6, b + 6, c + 6) for a, b, c in fan]
    for i in range(6):
        j = (i + 1) % 6
        faces += [(i, j, j + 6), (i, j + 6, i + 6)]
    return verts, np.array(faces)


def test_non_convex_mesh_is_decomposed(tmp_path):
    import trimesh
    from pxr import Gf, Usd, UsdGeom, Vt

    verts, faces = _l_prism()
    assert trimesh.Trimesh(verts, faces).is_watertight
    stage = Usd.Stage.CreateNew(str(tmp_path / "l.usda"))
    mesh = UsdGeom.Mesh.Define(stage, "/L")
    mesh.CreatePointsAttr(Vt.Vec3fArray([Gf.Vec3f(*map(float, p)) for p in verts]))
    mesh.CreateFaceVertexCountsAttr(Vt.IntArray([3] * len(faces)))
    mesh.CreateFaceVertexIndicesAttr(Vt.IntArray([int(x) for x in faces.ravel()]))
    stage.GetRootLayer().Save()
    out = read_part(tmp_path / "l.usda")
    assert len(out) >= 2  # coacd split it
    # no piece spans the notch of the L (the region x, y > 1 cm is empty)
    for piece in out:
        assert not ((piece[:, 0] > 0.0105).any() and (piece[:, 1] > 0.0105).any())


@pytest.mark.parametrize("kind", ["missing", "garbage", "no_mesh", "flat_mesh"])
def test_bad_usd_files_give_one_line_errors(tmp_path, kind):
    path = tmp_path / "bad.usda"
    if kind == "garbage":
        path.write_text("#usda 1.0\n(\n this is not usd {{{\n")
    elif kind == "no_mesh":
        from pxr import Usd, UsdGeom

        stage = Usd.Stage.CreateNew(str(path))
        UsdGeom.Xform.Define(stage, "/Empty")
        stage.GetRootLayer().Save()
    elif kind == "flat_mesh":  # a single quad: no volume, nothing MuJoCo can collide
        from pxr import Gf, Usd, UsdGeom, Vt

        stage = Usd.Stage.CreateNew(str(path))
        mesh = UsdGeom.Mesh.Define(stage, "/Quad")
        mesh.CreatePointsAttr(Vt.Vec3fArray([Gf.Vec3f(x, y, 0) for x, y in ((0, 0), (1, 0), (1, 1), (0, 1))]))
        mesh.CreateFaceVertexCountsAttr(Vt.IntArray([4]))
        mesh.CreateFaceVertexIndicesAttr(Vt.IntArray([0, 1, 2, 3]))
        stage.GetRootLayer().Save()
    with pytest.raises(AccrueError) as e:
        register_usd_task("mine/bad", path, path, depth=0.01)
    msg = str(e.value)
    assert "\n" not in msg and "bad.usda" in msg


def test_task_yaml(tmp_path):
    from accrue.sim.part_shapes import insertion_parts

    parts = insertion_parts("triangle", 0.3 * MM, 10 * MM, 0.7 * MM, 24 * MM)
    write_part(tmp_path / "p.usda", parts.plug)
    write_part(tmp_path / "s.usda", parts.socket)
    (tmp_path / "task.yaml").write_text(
        "task_id: mine/tri\nplug: p.usda\nsocket: s.usda\ndepth_mm: 10\nyaw_symmetry: 3\nmax_steps: 70\nreplace: true\n"
        "clearance: 0.0003\nchamfer: 0.0007\n"
    )
    spec = load_task_yaml(tmp_path / "task.yaml")
    assert spec.task_id == "mine/tri" and spec.max_steps == 70 and spec.depth == pytest.approx(0.01)
    env = make_vec_env("mine/tri", num_envs=1)
    assert env.reset()["state"].shape[0] == 1
    (tmp_path / "bad.yaml").write_text("task_id: mine/x\nplug: p.usda\n")
    with pytest.raises(AccrueError, match="socket"):
        load_task_yaml(tmp_path / "bad.yaml")
