"""User tasks from their own plug/socket USD files, registered in code or from a task YAML.

Frames expected in the files: the plug's origin at the centre of its bottom face, the
socket's origin at the centre of its opening, both Z up after metersPerUnit/upAxis are applied.
Non-convex meshes are split with coacd when loaded.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

from accrue.errors import AccrueError
from accrue.sim.tasks import MM, TaskSpec, add_task
from accrue.sim.usd_parts import read_part

_FIELDS = {f.name for f in dataclasses.fields(TaskSpec)}


def register_usd_task(
    task_id: str,
    plug_usd: str | Path,
    socket_usd: str | Path,
    *,
    depth: float,
    gripper_usd: str | Path | None = None,
    yaw_symmetry: int = 1,
    clearance: float = 0.0,
    instruction: str | None = None,
    replace: bool = False,
    **overrides,
) -> TaskSpec:
    """Register (and return) a task whose geometry comes from the given USD files (depth in metres)."""
    if not isinstance(task_id, str) or task_id.count("/") != 1 or not all(task_id.split("/")):
        raise AccrueError(f"task id must look like 'family/name', got {task_id!r}")
    unknown = set(overrides) - _FIELDS
    if unknown:
        raise AccrueError(f"unknown task field(s) for {task_id}: {', '.join(sorted(unknown))}")
    if not depth > 0:
        raise AccrueError(f"task {task_id}: depth must be > 0 (metres), got {depth}")
    paths = [Path(plug_usd), Path(socket_usd)] + ([Path(gripper_usd)] if gripper_usd else [])
    for p in paths:  # fail now, with the file named, rather than at the first reset
        read_part(p)
    family, name = task_id.split("/")
    spec = TaskSpec(
        task_id=task_id,
        family=family,
        instruction=instruction or f"insert the {name} plug",
        plug_usd=paths[0].resolve(),
        socket_usd=paths[1].resolve(),
        gripper_usd=paths[2].resolve() if gripper_usd else None,
        depth=float(depth),
        clearance=float(clearance),
        yaw_symmetry=int(yaw_symmetry),
        **overrides,
    )
    from accrue.sim.model import build_model

    build_model(spec)  # compile once so geometry MuJoCo rejects fails at registration, with the task named
    return add_task(spec, replace=replace)


def load_task_yaml(path: str | Path) -> TaskSpec:
    """Register a task from YAML: task_id, plug, socket, [gripper], depth_mm, [yaw_symmetry, max_steps, ...].

    File paths are relative to the YAML file.
    """
    import yaml

    path = Path(path)
    if not path.is_file():
        raise AccrueError(f"task file not found: {path}")
    try:
        doc = yaml.safe_load(path.read_text())
    except yaml.YAMLError as exc:
        raise AccrueError(f"cannot parse task file {path}: {str(exc).splitlines()[0]}") from None
    if not isinstance(doc, dict):
        raise AccrueError(f"task file {path} must hold a mapping")
    doc = dict(doc)
    try:
        task_id, plug, socket, depth_mm = doc.pop("task_id"), doc.pop("plug"), doc.pop("socket"), doc.pop("depth_mm")
    except KeyError as exc:
        raise AccrueError(f"task file {path} lacks field {exc.args[0]!r}") from None
    gripper = doc.pop("gripper", None)
    base = path.parent
    return register_usd_task(
        task_id,
        base / plug,
        base / socket,
        depth=float(depth_mm) * MM,
        gripper_usd=base / gripper if gripper else None,
        **doc,
    )
