"""USD Cube and Cylinder colliders: written and read back as MuJoCo boxes and cylinders (metersPerUnit, up
axis and transforms honoured), visual ones ignored, shapes MuJoCo cannot take refused in one line."""

import numpy as np
import pytest

from accrue.errors import AccrueError
from accrue.sim import geometry as g
from accrue.sim.usd_parts import read_part, write_part

MM = 1e-3


def _same(a: g.Primitive, b: g.Primitive) -> bool:
    return a.kind == b.kind and np.allclose(a.size + a.pos + a.quat, b.size + b.pos + b.quat, atol=1e-9)


def test_primitives_round_trip_beside_meshes(tmp_path):
    tilt = (np.cos(0.2), np.sin(0.2) / np.sqrt(2), 0.0, np.sin(0.2) / np.sqrt(2))
    pieces = [
        g.turned_box((0.01, -0.002, 0.004), (1.25 * MM, 1.2 * MM, 4 * MM), 2.7),  # w < 0 before canonical form
        g.prism(g.regular_polygon(6, 5 * MM), 0.0, 10 * MM),
        g.Primitive("cylinder", (3 * MM, 5 * MM), (0.0, 0.001, -0.005), tilt),
    ]
    write_part(tmp_path / "p.usda", pieces)
    back = read_part(tmp_path / "p.usda")
    assert [type(p).__name__ for p in back] == ["Primitive", "ndarray", "Primitive"]
    assert _same(back[0], pieces[0]) and _same(back[2], pieces[2])
    assert back[0].quat[0] >= 0


def _world_points(prim, local: np.ndarray) -> np.ndarray:
    """Local points of a prim through pxr's own transform, in metres, Z up (the file is cm, Y up)."""
    from pxr import UsdGeom

    m = np.asarray(UsdGeom.XformCache().GetLocalToWorldTransform(prim), dtype=float)
    p = (local @ m[:3, :3] + m[3, :3]) * 0.01
    return np.column_stack([p[:, 0], -p[:, 2], p[:, 1]])


def test_an_isaac_style_file_in_centimetres_y_up(tmp_path):
    from pxr import Gf, Usd, UsdGeom, UsdPhysics

    stage = Usd.Stage.CreateNew(str(tmp_path / "cm.usda"))
    UsdGeom.SetStageMetersPerUnit(stage, 0.01)
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    root = UsdGeom.Xform.Define(stage, "/Part")
    root.AddTranslateOp().Set(Gf.Vec3d(1.0, 2.0, -0.5))
    root.AddRotateYOp().Set(30.0)
    root.AddScaleOp().Set(Gf.Vec3d(2.0, 2.0, 2.0))
    cube = UsdGeom.Cube.Define(stage, "/Part/block")
    cube.CreateSizeAttr(1.0)
    cube.AddTranslateOp().Set(Gf.Vec3d(0.5, 0.0, 0.2))
    cube.AddRotateXYZOp().Set(Gf.Vec3f(10.0, 0.0, 25.0))
    cube.AddScaleOp().Set(Gf.Vec3f(1.0, 2.0, 0.5))
    cyl = UsdGeom.Cylinder.Define(stage, "/Part/pin")
    cyl.CreateRadiusAttr(0.3)
    cyl.CreateHeightAttr(4.0)
    cyl.CreateAxisAttr(UsdGeom.Tokens.x)
    cyl.AddTranslateOp().Set(Gf.Vec3d(0.0, 1.0, 0.0))
    for prim in (cube, cyl):
        UsdPhysics.CollisionAPI.Apply(prim.GetPrim())
    UsdGeom.Cube.Define(stage, "/Part/visual_only")  # no collider: not part of the collision geometry
    stage.GetRootLayer().Save()

    box, pin = read_part(tmp_path / "cm.usda")
    signs = np.array([[x, y, z] for x in (-0.5, 0.5) for y in (-0.5, 0.5) for z in (-0.5, 0.5)])
    expected = _world_points(cube.GetPrim(), signs)
    got = box.corners()
    assert box.kind == "box"
    assert max(np.min(np.linalg.norm(got - e, axis=1)) for e in expected) < 1e-9
    ends = _world_points(cyl.GetPrim(), np.array([[-2.0, 0.0, 0.0], [2.0, 0.0, 0.0]]))
    axis = pin.rotation()[:, 2] * pin.size[1]
    assert pin.kind == "cylinder" and pin.size[0] == pytest.approx(0.3 * 2 * 0.01)
    assert np.allclose(
        sorted(map(tuple, [np.asarray(pin.pos) - axis, np.asarray(pin.pos) + axis])), sorted(map(tuple, ends))
    )


@pytest.mark.parametrize("kind", ["sheared_box", "flattened_cylinder"])
def test_shapes_mujoco_cannot_take_are_refused_in_one_line(tmp_path, kind):
    from pxr import Gf, Usd, UsdGeom, UsdPhysics

    path = tmp_path / "bad.usda"
    stage = Usd.Stage.CreateNew(str(path))
    outer = UsdGeom.Xform.Define(stage, "/Part")
    if kind == "sheared_box":  # a non-uniform scale outside a rotation shears the box
        outer.AddScaleOp().Set(Gf.Vec3d(1.0, 3.0, 1.0))
        prim = UsdGeom.Cube.Define(stage, "/Part/b")
        prim.AddRotateZOp().Set(30.0)
    else:
        prim = UsdGeom.Cylinder.Define(stage, "/Part/c")
        prim.AddScaleOp().Set(Gf.Vec3d(1.0, 2.0, 1.0))  # across its z axis: an elliptic cylinder
    UsdPhysics.CollisionAPI.Apply(prim.GetPrim())
    stage.GetRootLayer().Save()
    with pytest.raises(AccrueError) as e:
        read_part(path)
    assert "\n" not in str(e.value) and "bad.usda" in str(e.value)


def test_a_user_task_from_primitive_parts_runs(tmp_path):
    from accrue.sim import expert_success_rate, register_usd_task
    from accrue.sim.part_shapes import cylinder_peg_parts

    parts = cylinder_peg_parts(0.25 * MM, 12 * MM, 0.6 * MM, 26 * MM)
    write_part(tmp_path / "plug.usda", parts.plug)
    write_part(tmp_path / "socket.usda", parts.socket)
    spec = register_usd_task(
        "mine/cylinder",
        tmp_path / "plug.usda",
        tmp_path / "socket.usda",
        depth=12 * MM,
        yaw_symmetry=0,
        clearance=0.25 * MM,
        chamfer=0.6 * MM,
        replace=True,
    )
    assert expert_success_rate(spec.task_id, 4, seed=0) >= 0.5
