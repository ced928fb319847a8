"""MuJoCo model of one task: fixed socket, floating gripper (3 slide + 3 hinge joints) holding the plug.

The gripper is driven by position actuators with stiffness kp, damping kv and a force limit:
an impedance-like controller evaluated inside MuJoCo's step, so contact forces stay bounded and
stepping costs no Python. The `ee` body frame is the plug frame (centre of the plug's bottom),
so the slide joints read the plug tip position in the socket frame directly.
"""

from __future__ import annotations

import functools

import numpy as np

from accrue.errors import AccrueError
from accrue.sim.geometry import Primitive, piece_top
from accrue.sim.tasks import TaskSpec
from accrue.sim.usd_parts import read_part

GRIPPER_MASS = 0.30  # kg, the object-specific gripper (its inertia dominates the held part's)
KP_POS, KP_ROT = 1500.0, 15.0  # N/m, N m/rad nominal stiffness (randomised by gain_scale)
FORCE_LIMIT, TORQUE_LIMIT = 12.0, 2.0  # N, N m: the controller never pushes harder
HINGE_ARMATURE = 2e-3
# stiff contacts (time constant = 2 physics steps) so sub-millimetre clearances are not squeezed through
CONTACT_SOLREF = [0.004, 1.0]
CONTACT_SOLIMP = [0.95, 0.99, 0.0005, 0.5, 2.0]
JOINTS = ("x", "y", "z", "roll", "pitch", "yaw")


def _critical_damping(kp: float, inertia: float) -> float:
    return 2.0 * np.sqrt(kp * inertia)


def damping_for(kp_pos: float, kp_rot: float, plug_mass: float) -> tuple[float, float]:
    return _critical_damping(kp_pos, GRIPPER_MASS + plug_mass), _critical_damping(kp_rot, HINGE_ARMATURE + 2e-4)


def _add_pieces(spec, body, pieces, prefix: str, *, collide: tuple[int, int], rgba, group: int):
    """One geom per piece, named prefix_000, ...: a mesh for a vertex array, a box or cylinder for a Primitive."""
    import mujoco

    primitive_types = {"box": mujoco.mjtGeom.mjGEOM_BOX, "cylinder": mujoco.mjtGeom.mjGEOM_CYLINDER}
    for i, piece in enumerate(pieces):
        name = f"{prefix}_{i:03d}"
        if isinstance(piece, Primitive):
            shape = {"type": primitive_types[piece.kind], "size": [*piece.size, 0.0][:3]}
            shape.update(pos=list(piece.pos), quat=list(piece.quat))
        else:
            spec.add_mesh(name=name, uservert=np.asarray(piece, dtype=float).ravel().tolist())
            shape = {"type": mujoco.mjtGeom.mjGEOM_MESH, "meshname": name}
        body.add_geom(
            name=name,
            **shape,
            contype=collide[0],
            conaffinity=collide[1],
            rgba=rgba,
            group=group,
            density=0.0,
            solref=CONTACT_SOLREF,
            solimp=CONTACT_SOLIMP,
        )


def build_spec(task: TaskSpec):
    """An MjSpec for the task (geometry read from the task's USD files)."""
    import mujoco

    plug, socket = read_part(task.plug_usd), read_part(task.socket_usd)
    gripper = read_part(task.gripper_usd) if task.gripper_usd is not None else []
    top = max(piece_top(p) for p in plug)

    spec = mujoco.MjSpec()
    spec.modelname = task.task_id.replace("/", "_")
    opt = spec.option
    opt.timestep = task.physics_dt
    opt.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    opt.cone = mujoco.mjtCone.mjCONE_ELLIPTIC
    opt.impratio = 10.0
    # multiccd (several contact points per flat face pair) is on by default in MuJoCo 4
    spec.compiler.degree = False
    spec.visual.global_.offwidth, spec.visual.global_.offheight = 256, 256

    world = spec.worldbody
    world.add_light(pos=[0.0, -0.05, 0.3], dir=[0.0, 0.15, -1.0], diffuse=[0.8, 0.8, 0.8])
    # the table the fixture stands on: a plug pushed beside the socket lands on it
    world.add_geom(
        name="socket_table",
        type=mujoco.mjtGeom.mjGEOM_PLANE,
        size=[0.1, 0.1, 0.01],
        pos=[0, 0, -task.depth - 0.004],
        rgba=[0.35, 0.37, 0.4, 1],
        contype=0,
        conaffinity=1,
        solref=CONTACT_SOLREF,
        solimp=CONTACT_SOLIMP,
    )
    _add_pieces(spec, world, socket, "socket", collide=(0, 1), rgba=[0.55, 0.6, 0.7, 1], group=0)
    world.add_camera(name="front", pos=[0.0, -0.09, 0.07], xyaxes=[1, 0, 0, 0, 0.6, 0.8], fovy=45)
    # a second view from the +x side (a robot's second camera: render_cameras [front, side]); cameras do not
    # enter the dynamics
    world.add_camera(name="side", pos=[0.09, 0.0, 0.07], xyaxes=[0, 1, 0, -0.6, 0, 0.8], fovy=45)

    ee = world.add_body(name="ee", gravcomp=1.0, mass=GRIPPER_MASS, inertia=[2e-4, 2e-4, 2e-4], explicitinertial=True)
    for axis, name in zip(np.eye(3), JOINTS[:3]):
        ee.add_joint(name=name, type=mujoco.mjtJoint.mjJNT_SLIDE, axis=axis.tolist())
    for axis, name in zip(np.eye(3), JOINTS[3:]):
        ee.add_joint(name=name, type=mujoco.mjtJoint.mjJNT_HINGE, axis=axis.tolist(), armature=HINGE_ARMATURE)
    _add_pieces(spec, ee, gripper, "gripper", collide=(0, 0), rgba=[0.2, 0.2, 0.22, 1], group=1)
    held = ee.add_body(
        name="plug", gravcomp=1.0, mass=task.plug_mass, inertia=[task.plug_mass * 1e-4] * 3, explicitinertial=True
    )
    _add_pieces(spec, held, plug, "plug", collide=(1, 0), rgba=[0.85, 0.55, 0.2, 1], group=0)
    held.add_site(name="wrist", pos=[0.0, 0.0, top])
    spec.add_sensor(
        name="wrist_force", type=mujoco.mjtSensor.mjSENS_FORCE, objtype=mujoco.mjtObj.mjOBJ_SITE, objname="wrist"
    )
    spec.add_sensor(
        name="wrist_torque", type=mujoco.mjtSensor.mjSENS_TORQUE, objtype=mujoco.mjtObj.mjOBJ_SITE, objname="wrist"
    )

    kv_pos, kv_rot = damping_for(KP_POS, KP_ROT, task.plug_mass)
    for i, name in enumerate(JOINTS):
        kp, kv, lim = (KP_POS, kv_pos, FORCE_LIMIT) if i < 3 else (KP_ROT, kv_rot, TORQUE_LIMIT)
        act = spec.add_actuator(name=name, target=name, trntype=mujoco.mjtTrn.mjTRN_JOINT)
        act.gaintype = mujoco.mjtGain.mjGAIN_FIXED
        act.biastype = mujoco.mjtBias.mjBIAS_AFFINE
        act.gainprm[0] = kp
        act.biasprm[0:3] = [0.0, -kp, -kv]
        act.forcelimited = mujoco.mjtLimited.mjLIMITED_TRUE
        act.forcerange = [-lim, lim]
    return spec


@functools.lru_cache(maxsize=64)
def _compiled(task: TaskSpec):
    try:
        return build_spec(task).compile()
    except ValueError as exc:  # e.g. a flat or degenerate mesh piece
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise AccrueError(f"task {task.task_id}: MuJoCo rejected its part geometry: {first}") from None


def build_model(task: TaskSpec):
    """The compiled MjModel (cached per task definition; callers must not mutate it)."""
    return _compiled(task)


def socket_geom_ids(model) -> np.ndarray:
    import mujoco

    names = [mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_GEOM, i) or "" for i in range(model.ngeom)]
    return np.array([i for i, n in enumerate(names) if n.startswith("socket_")], dtype=np.int64)
