"""Scripted-expert demonstrations written as LeRobotDataset v3 with lerobot's own writer.

Features follow lerobot's names: `observation.state` float32 (STATE_DIM,) named by STATE_NAMES,
`action` float32 (6,) (the normalised end-effector delta), `next.reward` float32 (1,),
`next.done` bool (1,), `next.success` bool (1,), and with obs_mode "state+image" the wrist
camera `observation.images.wrist` (mp4 video, or PNG images with `use_video=False` or frames
smaller than 32x32). Every frame's `task` is the task's instruction. Frame t holds the observation *before* action t and the
reward/done/success that action t produced; in a successful episode the last three frames carry
reward 1 (the paper's sparse reward, see INTERFACES.md).

Beside lerobot's metadata, `meta/accrue.json` records which accrue task the demos belong to,
how they were made (seed, expert quality, obs mode) and the expert's success rate.

Failed expert episodes: by default only successful episodes are kept. The vectorised env keeps
drawing fresh randomised episodes (its seeded generator) until `episodes` successes are written
or `max_attempts` expert episodes have been run; the summary says how many were run, how many
succeeded, and whether the requested count was reached.

The dataset is built in a hidden sibling directory (`.<name>.partial-<pid>`) and renamed into
place when complete; only a killed process (SIGKILL) can leave such a directory behind.

The demo writers (this module's `write_demos`, accrue.robot.demo_convert's lerobot-record conversion,
accrue.robot.sim_robot.so101_demos) share this layout and its writing rules through a small API:
`demo_features` (the feature spec), `check_out_dir` (the output must be new or empty),
`label_success_tail` (the sparse reward of a successful episode), `save_episode` (its frames into the
dataset being written), `staged_dataset` (build in the hidden sibling, publish on success, remove on
failure; `publish` is its rename step) and `write_json_atomic` (meta/accrue.json).
"""

from __future__ import annotations

import json
import os
import shutil
import warnings
from contextlib import contextmanager
from dataclasses import asdict, dataclass
from pathlib import Path
from types import ModuleType
from typing import Any, Callable, Iterator, NamedTuple

import numpy as np

from accrue.errors import AccrueError
from accrue.process_tmp import process_alive

ACTION_DIM = 6
ACTION_NAMES = ["dx", "dy", "dz", "droll", "dpitch", "dyaw"]
STATE_KEY = "observation.state"
ACTION_KEY = "action"
IMAGE_KEY = "observation.images.wrist"
REWARD_KEY, DONE_KEY, SUCCESS_KEY = "next.reward", "next.done", "next.success"
ACCRUE_META = Path("meta") / "accrue.json"
OBS_MODES = ("state", "state+image")
ACCRUE_META_FORMAT = 1
MIN_VIDEO_SIDE = 32
SUCCESS_TAIL = 3
LEROBOT_FORMAT = "v3.0"


def _sim_api() -> ModuleType:
    """The simulator package (a seam so tests can substitute a small fake)."""
    import accrue.sim as sim

    return sim


def get_task_spec(task_id: str) -> Any:
    """The simulator's TaskSpec; an unknown id is a one-line AccrueError listing the known ones."""
    sim = _sim_api()
    try:
        return sim.get_task(task_id)
    except AccrueError:
        raise
    except (KeyError, ValueError):
        known = ", ".join(sim.list_tasks())
        raise AccrueError(f"unknown task {task_id!r}; known tasks: {known}") from None


@dataclass(frozen=True)
class DemoSummary:
    root: Path
    task_id: str
    instruction: str
    requested: int
    episodes: int  # episodes written
    frames: int
    attempts: int  # expert episodes run (written or not)
    successes: int
    seed: int
    quality: float
    obs_mode: str
    search: bool = True  # the expert searches when stuck (False: acts on the current observation only)
    bias_known: float = 1.0  # fraction of the fixture's estimate bias the expert corrects

    @property
    def expert_success_rate(self) -> float:
        return self.successes / self.attempts if self.attempts else 0.0

    @property
    def complete(self) -> bool:
        return self.episodes == self.requested


class DemoInfo(NamedTuple):
    task_id: str
    instruction: str
    num_episodes: int
    features: dict


def repo_id_for(task_id: str) -> str:
    """A local lerobot repo id for a task ("plugs/cross" -> "accrue/plugs_cross")."""
    return "accrue/" + task_id.replace("/", "_")


def demo_features(
    state_names: list[str],
    image_shape: tuple[int, int, int] | None = None,
    use_video: bool = True,
    image_key: str = IMAGE_KEY,  # a robot's demos name their camera: observation.images.<its key>
) -> dict:
    """lerobot feature spec for accrue demos. Shapes are tuples: lerobot compares them to ndarray shapes."""
    features: dict[str, dict[str, Any]] = {
        STATE_KEY: {"dtype": "float32", "shape": (len(state_names),), "names": list(state_names)},
        ACTION_KEY: {"dtype": "float32", "shape": (ACTION_DIM,), "names": list(ACTION_NAMES)},
        REWARD_KEY: {"dtype": "float32", "shape": (1,), "names": None},
        DONE_KEY: {"dtype": "bool", "shape": (1,), "names": None},
        SUCCESS_KEY: {"dtype": "bool", "shape": (1,), "names": None},
    }
    if image_shape is not None:
        # the AV1 encoder kills the process (SIGFPE) on frames below 32x32: store those as PNGs
        use_video = use_video and min(image_shape[:2]) >= MIN_VIDEO_SIDE
        features[image_key] = {
            "dtype": "video" if use_video else "image",
            "shape": tuple(int(s) for s in image_shape),
            "names": ["height", "width", "channels"],
        }
    return features


def check_out_dir(out_dir: Path) -> None:
    """A demo writer's output: a new or empty directory (its parent is made); else a one-line AccrueError."""
    if out_dir.exists():
        if not out_dir.is_dir():
            raise AccrueError(f"output path {out_dir} exists and is not a directory")
        if any(out_dir.iterdir()):
            raise AccrueError(f"output directory {out_dir} exists and is not empty; pick a new one")
    out_dir.parent.mkdir(parents=True, exist_ok=True)


def label_success_tail(frames: list[dict]) -> None:
    """The paper's sparse reward: the last SUCCESS_TAIL steps of a successful episode carry 1 (in place).

    A single env.step() can only reward the step that succeeded, so the tail is labelled here.
    """
    for frame in frames[-SUCCESS_TAIL:]:
        frame[REWARD_KEY] = np.maximum(frame[REWARD_KEY], np.float32(1.0))


def save_episode(ds: Any, frames: list[dict]) -> None:
    """Add an episode's frames to the LeRobotDataset being written and save it as one episode."""
    for frame in frames:
        ds.add_frame(frame)
    with warnings.catch_warnings():
        # lerobot's histogram of bool columns warns on every episode; harmless
        warnings.filterwarnings("ignore", "Converting input from bool", RuntimeWarning)
        ds.save_episode()


def write_json_atomic(path: Path, data: dict) -> None:
    """`data` as indented JSON at `path`, written beside it and renamed over it (never half a file)."""
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(data, indent=2) + "\n")
    os.replace(tmp, path)


class _Progress:
    """Rich progress on stderr, or nothing."""

    def __init__(self, enabled: bool, total: int, label: str) -> None:
        self._bar = None
        if enabled:
            from rich.console import Console
            from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

            self._bar = Progress(
                TextColumn("{task.description}"),
                BarColumn(),
                MofNCompleteColumn(),
                TextColumn("{task.fields[note]}"),
                TimeElapsedColumn(),
                console=Console(stderr=True),
                transient=False,
            )
            self._task = self._bar.add_task(label, total=total, note="")
            self._bar.start()

    def update(self, written: int, attempts: int, successes: int) -> None:
        if self._bar is not None:
            note = f"expert {successes}/{attempts} succeeded" if attempts else ""
            self._bar.update(self._task, completed=written, note=note)

    def stop(self) -> None:
        if self._bar is not None:
            self._bar.stop()


@dataclass
class _Episode:
    frames: list[dict]
    success: bool


def _expert_episodes(
    env: Any, expert: Any, obs: dict, instruction: str, max_attempts: int, still_needed: Callable[[], int]
) -> Iterator[_Episode]:
    """Finished expert episodes from the vectorised env, in the order they end.

    An env that finishes starts another episode only while fewer episodes are running than
    `still_needed()` and fewer than `max_attempts` have been started.
    """
    states0 = np.asarray(obs["state"])
    n = len(states0)
    with_image = "image" in obs
    frames: list[list[dict]] = [[] for _ in range(n)]
    active = np.ones(n, dtype=bool)  # env i runs an episode that will be counted
    started = n
    while active.any():
        states = np.asarray(obs["state"], dtype=np.float32)
        images = np.asarray(obs["image"]) if with_image else None
        actions = np.clip(np.asarray(expert.act(states), dtype=np.float32), -1.0, 1.0)
        res = env.step(actions)
        rewards = np.asarray(res.reward, dtype=np.float32).reshape(n)
        success = np.asarray(res.success, dtype=bool).reshape(n)
        done = np.asarray(res.terminated, dtype=bool).reshape(n) | np.asarray(res.truncated, dtype=bool).reshape(n)
        for i in np.flatnonzero(active):
            frame = {
                STATE_KEY: states[i].copy(),
                ACTION_KEY: actions[i].copy(),
                REWARD_KEY: np.array([rewards[i]], dtype=np.float32),
                DONE_KEY: np.array([done[i]]),
                SUCCESS_KEY: np.array([success[i]]),
                "task": instruction,
            }
            if images is not None:
                frame[IMAGE_KEY] = images[i].copy()
            frames[i].append(frame)
        for i in np.flatnonzero(done & active):
            yield _Episode(frames[i], bool(success[i]))
            frames[i] = []
            running_elsewhere = int(active.sum()) - 1
            if started < max_attempts and still_needed() > running_elsewhere:
                started += 1
            else:
                active[i] = False
        obs = env.reset(done) if done.any() else res.obs


def write_demos(
    task_id: str,
    episodes: int,
    out_dir: Path,
    seed: int = 0,
    quality: float = 1.0,
    obs_mode: str = "state",
    only_successful: bool = True,
    progress: bool = True,
    *,
    num_envs: int | None = None,
    max_attempts: int | None = None,
    use_video: bool = True,
    search: bool = True,
    bias_known: float = 1.0,
) -> DemoSummary:
    """Run the scripted expert of `task_id` in the vectorised env; write `episodes` episodes to `out_dir`.

    `max_attempts` bounds the expert episodes run (default `max(3 * episodes, episodes + 8)`);
    if it is reached first, the episodes written so far still form a valid dataset and the
    summary's `complete` is False. `out_dir` must not exist or be empty. The dataset is built
    under a temporary sibling name and renamed to `out_dir` when finished, so an interrupted
    run leaves nothing under `out_dir`. `search` and `bias_known` choose the demonstrator
    (`accrue.sim.expert.ScriptedExpert`).
    """
    if episodes < 1:
        raise AccrueError(f"episodes must be at least 1, got {episodes}")
    if obs_mode not in OBS_MODES:
        raise AccrueError(f"obs_mode must be one of {', '.join(OBS_MODES)}, got {obs_mode!r}")
    out_dir = Path(out_dir)
    sim = _sim_api()
    spec = get_task_spec(task_id)
    check_out_dir(out_dir)
    max_attempts = max(3 * episodes, episodes + 8) if max_attempts is None else max(int(max_attempts), 1)
    n = max(1, min(num_envs or 8, episodes, max_attempts))

    env = sim.make_vec_env(task_id, num_envs=n, seed=seed, obs_mode=obs_mode)
    expert = sim.make_expert(task_id, quality=quality, seed=seed, search=search, bias_known=bias_known)
    obs = env.reset()
    image_shape = tuple(np.asarray(obs["image"]).shape[1:]) if obs_mode == "state+image" else None
    features = demo_features(list(sim.STATE_NAMES), image_shape, use_video)

    os.environ.setdefault("SVT_LOG", "1")  # the AV1 encoder prints its whole config per video otherwise
    import datasets
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    bars_were_on = not datasets.are_progress_bars_disabled()
    datasets.disable_progress_bars()  # one "Map" bar per saved episode otherwise; ours suffices
    bar = _Progress(progress, episodes, f"demos {task_id}")
    attempts = successes = written = total_frames = 0
    try:
        with staged_dataset(out_dir) as staging:
            ds = LeRobotDataset.create(
                repo_id=repo_id_for(task_id),
                root=staging,
                fps=int(round(spec.control_hz)),
                features=features,
                use_videos=any(f["dtype"] == "video" for f in features.values()),
                video_backend="pyav",
            )
            try:
                still_needed = lambda: episodes - written  # noqa: E731,B023 - reads the count as it grows
                for ep in _expert_episodes(env, expert, obs, spec.instruction, max_attempts, still_needed):
                    attempts += 1
                    successes += int(ep.success)
                    if (ep.success or not only_successful) and written < episodes:
                        if ep.success:
                            label_success_tail(ep.frames)
                        save_episode(ds, ep.frames)
                        written += 1
                        total_frames += len(ep.frames)
                    bar.update(written, attempts, successes)
                    if written == episodes:
                        break
            finally:
                ds.finalize()
            _sort_stats_keys(staging / "meta" / "stats.json")
            if written == 0:
                raise AccrueError(
                    f"the {task_id} expert (quality {quality}) succeeded in none of {attempts} episodes; nothing written"
                )
            summary = DemoSummary(
                root=out_dir,
                task_id=task_id,
                instruction=spec.instruction,
                requested=episodes,
                episodes=written,
                frames=total_frames,
                attempts=attempts,
                successes=successes,
                seed=seed,
                quality=float(quality),
                obs_mode=obs_mode,
                search=bool(search),
                bias_known=float(bias_known),
            )
            write_json_atomic(staging / ACCRUE_META, _accrue_meta(summary, only_successful, list(sim.STATE_NAMES)))
    finally:
        bar.stop()
        if bars_were_on:
            datasets.enable_progress_bars()
        if hasattr(env, "close"):
            env.close()
    return summary


def _sort_stats_keys(path: Path) -> None:
    """lerobot writes stats.json's keys in an order that changes between processes; sorted, the same
    demos give the same bytes (accrue/policy/training_set.py sorts its merged set's likewise)."""
    if path.is_file():
        path.write_text(
            json.dumps(json.loads(path.read_text(encoding="utf-8")), indent=4, sort_keys=True), encoding="utf-8"
        )


def _remove_stale_staging(out_dir: Path) -> None:
    """Delete staging directories of earlier runs into `out_dir` whose process no longer exists.

    Not accrue.process_tmp.sweep_dead, on purpose: the staging name is `.<name>.partial-<pid>` with
    nothing after the pid (sweep_dead matches `<prefix><pid>-*`; demo_convert, so101_demos and the
    demos tests use this name too), and it is a fixed function of the pid, so a leftover whose pid this
    process now has (pids are reused, in containers soon) must go as well - LeRobotDataset.create
    refuses a root that exists - where sweep_dead always spares this process's own directories."""
    prefix = f".{out_dir.name}.partial-"
    for path in out_dir.parent.glob(prefix + "*"):
        pid = path.name[len(prefix) :]
        if pid.isdigit() and (int(pid) == os.getpid() or not process_alive(int(pid))):
            shutil.rmtree(path, ignore_errors=True)


def publish(staging: Path, out_dir: Path) -> None:
    """Rename the finished dataset at `staging` to `out_dir` (absent, or the empty directory check_out_dir let
    through)."""
    if out_dir.exists():
        out_dir.rmdir()  # still empty (checked at the start); fails loudly if someone wrote there since
    os.replace(staging, out_dir)


@contextmanager
def staged_dataset(out_dir: Path) -> Iterator[Path]:
    """The hidden sibling `.<name>.partial-<pid>` of out_dir to build a dataset in (earlier runs' leftovers
    removed first). When the block ends normally it is published as out_dir; when it raises, or is
    interrupted, it is removed and out_dir stays as it was. Call check_out_dir(out_dir) before."""
    _remove_stale_staging(out_dir)
    staging = out_dir.with_name(f".{out_dir.name}.partial-{os.getpid()}")
    try:
        yield staging
        publish(staging, out_dir)
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise


def _accrue_meta(summary: DemoSummary, only_successful: bool, state_names: list[str]) -> dict:
    meta = {k: v for k, v in asdict(summary).items() if k != "root"}
    meta.update(
        format=ACCRUE_META_FORMAT,
        only_successful=only_successful,
        expert_success_rate=summary.expert_success_rate,
        state_names=state_names,
    )
    return meta


def _expect(features: dict, root: Path, key: str, dtype: str, shape: list[int], why: str = "") -> None:
    feat = features.get(key)
    if feat is None:
        raise AccrueError(f"dataset {root} lacks feature '{key}'")
    if feat.get("dtype") != dtype:
        raise AccrueError(f"dataset {root}: feature '{key}' has dtype {feat.get('dtype')}, expected {dtype}")
    if list(feat.get("shape", [])) != shape:
        raise AccrueError(
            f"dataset {root}: feature '{key}' has shape {list(feat.get('shape', []))}, expected {shape}{why}"
        )


def read_demo_info(root: Path | str, *, state_dim: int | None = None) -> DemoInfo:
    """Task id, instruction, episode count and features of an accrue demo dataset, after checking its features.

    `state_dim` defaults to the simulator's STATE_DIM. Any mismatch is an AccrueError naming the feature.
    """
    root = Path(root)
    info_path = root / "meta" / "info.json"
    if not info_path.is_file():
        raise AccrueError(f"{root} is not a LeRobot dataset (no meta/info.json)")
    try:
        info = json.loads(info_path.read_text())
        features = dict(info["features"])
        num_episodes = int(info["total_episodes"])
        version = str(info.get("codebase_version"))
    except (ValueError, KeyError, TypeError) as exc:
        raise AccrueError(f"{info_path} is unreadable ({type(exc).__name__}: {exc})") from None
    if version != LEROBOT_FORMAT:
        raise AccrueError(f"dataset {root} is LeRobotDataset {version}; accrue reads {LEROBOT_FORMAT}")
    if state_dim is None:
        state_dim = int(_sim_api().STATE_DIM)
    _expect(features, root, STATE_KEY, "float32", [state_dim], " (accrue's STATE_DIM)")
    _expect(features, root, ACTION_KEY, "float32", [ACTION_DIM], " (6-D end-effector delta)")
    _expect(features, root, REWARD_KEY, "float32", [1])
    _expect(features, root, DONE_KEY, "bool", [1])
    _expect(features, root, SUCCESS_KEY, "bool", [1])
    if IMAGE_KEY in features:
        image = features[IMAGE_KEY]
        if (
            image.get("dtype") not in ("video", "image")
            or len(image.get("shape", [])) != 3
            or list(image["shape"])[2] != 3
        ):
            raise AccrueError(f"dataset {root}: feature '{IMAGE_KEY}' must be an RGB video or image (h, w, 3)")
    meta_path = root / ACCRUE_META
    if not meta_path.is_file():
        raise AccrueError(f"dataset {root} has no {ACCRUE_META.as_posix()}, so its accrue task is unknown")
    try:
        meta = json.loads(meta_path.read_text())
        task_id, instruction = str(meta["task_id"]), str(meta["instruction"])
    except (ValueError, KeyError, TypeError) as exc:
        raise AccrueError(f"{meta_path} is unreadable ({type(exc).__name__}: {exc})") from None
    if num_episodes < 1:
        raise AccrueError(f"dataset {root} has no episodes")
    return DemoInfo(task_id=task_id, instruction=instruction, num_episodes=num_episodes, features=features)
