"""lerobot robot (and teleoperator) types by name: `so101_follower` finds lerobot.robots.so_follower without an
`imports:` line, `keyboard_ee` lerobot.teleoperators.keyboard.

lerobot registers a robot type when its config module is imported, and only its own scripts import them.
`builtin_module(type)` reads lerobot/robots/*/ for `register_subclass("<type>")` (no import, so a robot
whose SDK is absent does not stop the others), and `import_robot_module` imports it; a missing SDK is one
line naming the pip extra that provides it.
"""

from __future__ import annotations

import importlib
import re
from functools import lru_cache
from pathlib import Path

from accrue.errors import AccrueError

# the module a robot driver imports -> lerobot's extra that installs it (lerobot 0.6.1's pyproject)
EXTRA_OF_MODULE = {
    "scservo_sdk": "feetech",
    "dynamixel_sdk": "dynamixel",
    "reachy2_sdk": "reachy2",
    "zmq": "lekiwi",
    "can": "damiao",
    "placo": "kinematics",
    "pyrealsense2": "intelrealsense",
    "unitree_sdk2py": "unitree-g1",
    "pygame": "hopejr",
}

# lerobot 0.6's require_package(): "'feetech-servo-sdk' is required but not installed. Install it with: pip
# install 'lerobot[feetech]' (or ...)", raised when the robot is built, before the SDK is imported
_REQUIRED = re.compile(r"""'([^']+)' is required but not installed\. Install it with: pip install '([^']+)'""")
_REGISTER = re.compile(r"""register_subclass\(\s*["']([A-Za-z0-9_\-]+)["']""")


def _registered(package: str) -> dict[str, str]:
    """{type: module that registers it} for the subpackages of lerobot `package` (read, not imported)."""
    root = Path(importlib.import_module(package).__file__).parent
    out: dict[str, str] = {}
    for py in sorted(root.glob("*/*.py")):
        for name in _REGISTER.findall(py.read_text(encoding="utf-8", errors="replace")):
            out.setdefault(name, f"{package}.{py.parent.name}")
    return out


@lru_cache(maxsize=1)
def builtin_types() -> dict[str, str]:
    """{robot type: lerobot module that registers it} for lerobot's own robots."""
    return _registered("lerobot.robots")


def builtin_module(robot_type: str) -> str | None:
    return builtin_types().get(robot_type)


@lru_cache(maxsize=1)
def builtin_teleop_types() -> dict[str, str]:
    """{teleoperator type: lerobot module that registers it} for lerobot's own teleoperators."""
    return _registered("lerobot.teleoperators")


def import_robot_module(module: str, why: str) -> None:
    """Import `module`; a missing dependency is one AccrueError line with the extra to install."""
    try:
        importlib.import_module(module)
    except ModuleNotFoundError as exc:
        raise missing_dependency(exc, why, module) from None
    except ImportError as exc:
        raise AccrueError(f"{why}: cannot import {module!r} ({exc})") from None


def missing_requirement(exc: ImportError, why: str, what: str) -> AccrueError | None:
    """lerobot's own "package is required" ImportError as one line in missing_dependency's form; else None."""
    found = _REQUIRED.search(str(exc))
    if found is None:
        return None
    return AccrueError(f"{why}: {what} needs {found[1]!r}, which is not installed (pip install '{found[2]}')")


def missing_dependency(exc: ModuleNotFoundError, why: str, what: str) -> AccrueError:
    """`why: what needs 'scservo_sdk', which is not installed (pip install 'lerobot[feetech]')`."""
    missing = (exc.name or "").split(".")[0]
    extra = EXTRA_OF_MODULE.get(missing)
    hint = f"pip install 'lerobot[{extra}]'" if extra else f"install the package that provides {missing!r}"
    return AccrueError(f"{why}: {what} needs {missing!r}, which is not installed ({hint})")
