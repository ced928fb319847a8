"""lerobot robot (and teleoperator) types by name: `so101_follower` finds lerobot.robots.so_follower without an
`imports:` line, `keyboard_ee` lerobot.teleoperators.keyboard.

lerobot registers a robot type when its config module is imported, and only its own scripts import them.
`builtin_module(type)` reads lerobot/robots/*/ for `register_subclass("<type>")` (no import, so a robot
whose SDK is absent does not stop the others), and `import_robot_module` imports it; a missing SDK is one
line naming the pip extra that provides it. `lerobot_factory` is the whole path from a type name and its
config to a function building the device, shared by the robot (`accrue.robot.bridge.robot_factory`) and
the intervention's teleoperator (`accrue.robot.teleop.teleop_factory`).
"""

from __future__ import annotations

import importlib
import re
from functools import lru_cache
from pathlib import Path
from typing import Any, Callable

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


def _lerobot_kind(kind: str) -> tuple[Any, Callable[[Any], Any], dict[str, str]]:
    """(config registry, lerobot's make_*_from_config, {builtin type: module}) for `robot` / `teleoperator`."""
    if kind == "robot":
        from lerobot.robots.config import RobotConfig
        from lerobot.robots.utils import make_robot_from_config

        return RobotConfig, make_robot_from_config, builtin_types()
    if kind != "teleoperator":
        raise ValueError(f"lerobot kind {kind!r}: robot or teleoperator")
    from lerobot.teleoperators.config import TeleoperatorConfig
    from lerobot.teleoperators.utils import make_teleoperator_from_config

    return TeleoperatorConfig, make_teleoperator_from_config, builtin_teleop_types()


def lerobot_factory(
    kind: str, type_name: str, config: dict[str, Any], imports: tuple[str, ...], *, where: str, type_key: str
) -> Callable[[], Any]:
    """A function building lerobot's `kind` ("robot" or "teleoperator") of `type_name` from `config`.

    The workflow names it as `<where>.<type_key>` (`robot.type`, `robot.intervention.teleop`), with
    `<where>.config` and `<where>.imports` beside it. The `imports` modules (and accrue's simulated robot and
    expert) are imported first so that third-party types register; one of lerobot's own types is found by
    name; an installed lerobot_{robot,teleoperator,...}_* plugin distribution without an imports line, as
    lerobot 0.6's own scripts find it (register_third_party_plugins). Every user mistake is one line: an
    unknown type, a config field the type's config class refuses, a package the device needs (with the
    extra that installs it; raised by the returned function, where lerobot checks it)."""
    cls = config_class(kind, type_name, imports, where=where, type_key=type_key)
    make_from_config = _lerobot_kind(kind)[1]
    field = f"{where}.{type_key}"
    device_config = decode_config(cls, config, f"{where}.config")
    package = cls.__module__.rsplit(".", 1)[0]

    def make():
        try:
            return make_from_config(device_config)
        except ModuleNotFoundError as exc:  # the driver's SDK (lerobot imports it when the device is built)
            raise missing_dependency(exc, f"{field} {type_name}", package) from None
        except ImportError as exc:  # lerobot 0.6 checks for the package first and names its extra itself
            line = missing_requirement(exc, f"{field} {type_name}", package)
            if line is None:
                raise
            raise line from None

    return make


def decode_config(cls: type, config: dict[str, Any], where: str):
    """`config` as an instance of lerobot config class `cls` (draccus checks each value's type and the class's
    own checks run); a value it refuses is one AccrueError line naming `where`."""
    try:
        import draccus

        return draccus.decode(cls, dict(config))
    except Exception as exc:  # noqa: BLE001 - draccus raises many types for a bad field
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise AccrueError(f"{where}: not a valid {cls.__name__} ({first})") from None


_REGISTER_ANY = re.compile(r"""(\w*)\.register_subclass\(\s*["']([A-Za-z0-9_\-]+)["']""")
_PLUGIN_PREFIXES = {"robot": ("lerobot_robot_", "lerobot-robot-"), "teleoperator": ("lerobot_teleoperator_",)}


def _source_names(files) -> dict[str, str]:
    """{registered name: the config class it is registered on} in the Python source `files` (read, not run)."""
    out: dict[str, str] = {}
    for py in files:
        try:
            text = Path(py).read_text(encoding="utf-8", errors="replace")
        except OSError:
            continue
        for owner, name in _REGISTER_ANY.findall(text):
            out.setdefault(name, owner)
    return out


def _package_files(module: str) -> list[Path] | None:
    """The .py files of the top-level package of `module`, found without importing anything; None when
    that package is not installed (the import then says so itself)."""
    import importlib.util

    try:
        spec = importlib.util.find_spec(module.split(".")[0])
    except (ImportError, ValueError):
        return None
    if spec is None:
        return None
    roots = list(spec.submodule_search_locations or [])
    if not roots:
        return [Path(spec.origin)] if spec.origin else []
    return [py for root in roots for py in Path(root).rglob("*.py")]


def written_type_names(kind: str, imports: tuple[str, ...]) -> tuple[set[str], set[str]] | None:
    """(every name any register_subclass call registers, those of `kind`'s own config class) in the source of
    lerobot's own `kind`s, accrue's simulated ones, the `imports` packages and installed lerobot_{kind}_*
    plugins: found in well under a second, where importing them takes tens (torch). None when a package to
    read is not installed: then only the import can say."""
    import importlib.metadata

    package = "robots" if kind == "robot" else "teleoperators"
    files = _package_files("lerobot")
    if files is None:
        return None
    files = [py for py in files if f"{Path('lerobot') / package}" in str(py)]
    files += list((Path(__file__).parent / "sim_robot").glob("*.py"))
    for module in imports:
        found = _package_files(module)
        if found is None:
            return None
        files += found
    for dist in importlib.metadata.distributions():
        name = str(dist.metadata.get("Name") or "")
        if name.lower().startswith(_PLUGIN_PREFIXES[kind]):
            files += [dist.locate_file(f) for f in dist.files or () if str(f).endswith(".py")]
            found = _package_files(name.replace("-", "_"))  # lerobot imports the distribution by its name
            if found is None and not dist.files:
                return None  # nothing of it to read: only lerobot's own import can say what it registers
            files += found or []
    names = _source_names(files)
    owner = "Robot" if kind == "robot" else "Teleoperator"
    return set(names), {n for n, cls in names.items() if cls.endswith(owner + "Config")}


def config_class(kind: str, type_name: str, imports: tuple[str, ...], *, where: str, type_key: str) -> type:
    """The lerobot config class of `kind` ("robot" or "teleoperator") `type_name`, found as lerobot_factory
    finds it: the `imports` first, then lerobot's own types, then installed plugins (one AccrueError line
    for an unknown type or a module that cannot be imported). A name no installed source registers (a
    typo) is refused first, from the source alone (written_type_names), before the slow imports."""
    field = f"{where}.{type_key}"
    written = written_type_names(kind, imports)
    if written is not None and type_name not in written[0]:
        raise unknown_type(kind, type_name, written[1], where, type_key)
    for name in ("accrue.robot.sim_robot", *imports):
        import_robot_module(name, f"{where}.imports")
    registry, _, builtin = _lerobot_kind(kind)
    if type_name not in registry.get_known_choices() and type_name in builtin:
        # one of lerobot's own: its module registers it (and names the extra it lacks)
        import_robot_module(builtin[type_name], f"{field} {type_name}")
    if type_name not in registry.get_known_choices():
        from lerobot.utils.import_utils import register_third_party_plugins

        register_third_party_plugins()  # imports every installed lerobot_{robot,teleoperator,...}_* distribution
    if type_name not in registry.get_known_choices():
        raise unknown_type(kind, type_name, set(registry.get_known_choices()) | set(builtin), where, type_key)
    return registry.get_choice_class(type_name)


def unknown_type(kind: str, type_name: str, known: set[str], where: str, type_key: str) -> AccrueError:
    """`robot.type: unknown lerobot robot type 'so101_evn' (did you mean 'so101_env'? known: ...)`."""
    import difflib

    close = difflib.get_close_matches(type_name, sorted(known), n=1)
    hint = f"did you mean {close[0]!r}? " if close else ""
    return AccrueError(
        f"{where}.{type_key}: unknown lerobot {kind} type {type_name!r} ({hint}known: {', '.join(sorted(known))}; "
        f"a third-party {kind}'s module goes in {where}.imports)"
    )
