"""`train` on a robot (paper Sec. V-C): an asynchronous actor (this process, on the robot at the control
rate) and learner (another process, here or on a GPU host, over gRPC), operator-labelled sparse rewards,
stopping when the running success over the last `stop_window` episodes reaches `stop_successes` (19/20)
or the robot-time budget is spent.

Resumable across days: every labelled episode and every `checkpoint_every` learner updates are sealed
at once (stages.steps.hw_session); `--continue` reloads the last learner checkpoint and every sealed
episode, so episodes, the 20-episode window and RL robot time continue where they stopped.

Outputs as the simulated `train` step (checkpoint, replay) plus `curve` (curve.json with "hardware": true:
every episode's label and robot time, the stop rule and when it was reached) and `episodes`.
"""

from __future__ import annotations

import contextlib
import shutil
import threading
from pathlib import Path

from stages.runner_context import StepContext
from stages.runner_types import StepDef
from stages.steps import handoff as handoff_step
from stages.steps import train as train_step
from stages.steps import warmup as warmup_step
from stages.steps.common import deterministic, load_base_policy, per_task_features, read_json, reference_fn, write_json
from stages.steps.hw_session import (
    HardwareSession,
    LearnerHold,
    SessionSettings,
    SessionStop,
    StopSignals,
    children_keep_sigint,
    episode_loop,
    episodes_output,
    make_bridge,
    make_operator,
    release_robot,
)


def episode_settings(c: dict, task: str, clock: float):
    from accrue.robot.episode import EpisodeSettings
    from accrue.robot.safety import SafetyEnvelope
    from accrue.sim import get_task

    spec = get_task(task)
    r = c["robot"]
    return EpisodeSettings(
        horizon=c["horizon"],
        max_steps=int(r.get("episode_steps") or spec.max_steps),
        control_hz=float(r.get("control_hz") or spec.control_hz),
        clock=clock,
        safety=SafetyEnvelope.from_dict(r.get("safety")),
    )


def update_target(session: HardwareSession, cfg) -> int:
    """The learner's update count once it has trained on every sealed episode: utd updates per chunk
    transition of the current task (accrue.robot.learner_service's train_forever)."""
    return int(sum(e["chunks"] for e in session.ordered("train")) * cfg.utd)


def final_weights(link, target: int, publish_every: int, wait_s: float) -> None:
    """Before the handoff: wait (up to wait_s of wall time) until the learner has made `target` updates,
    then take its state as it is then. Snapshots come every publish_every updates, so the wait watches
    them until the learner is within one of the target, then asks for a fresh one until it is reached."""
    import time

    deadline = time.monotonic() + wait_s
    while link.updates + publish_every < target and time.monotonic() < deadline:
        time.sleep(0.2)
    while True:
        left = deadline - time.monotonic()
        link.final_snapshot(wait_s=max(1.0, min(15.0, left)))
        if link.updates >= target or time.monotonic() >= deadline:
            return
        time.sleep(min(1.0, max(0.0, deadline - time.monotonic())))


def shortfall(ctx: StepContext, session: HardwareSession, target: int, waited_s: float) -> None:
    """The learner handed to the next stage, against the updates an uninterrupted learner makes: the
    shortfall is recorded in learner.json (and so in the checkpoint), the audit log and printed."""
    path = session.dir / "learner.json"
    info = read_json(path)
    short = max(0, target - int(info["updates"]))
    info.update(update_target=target, updates_short=short)
    write_json(path, info)
    if short:
        line = (
            f"train: the learner made {info['updates']} of {target} updates before the handoff "
            f"(waited up to robot.handoff_wait_s {waited_s:g} s); the next stage starts from it, short by {short}"
        )
        ctx.console.print(line, soft_wrap=True)
        session._log("robot-learner-shortfall", updates=int(info["updates"]), target=target, short=short)


def learner_tracking(ctx: StepContext, settings: SessionSettings, stage: int) -> dict:
    """What the learner needs to write its scalars (accrue.robot.learner_service): the workflow's
    tracking section (SessionSettings.tracking where the plan binds it, else the defaults) and the
    run .../stage-<k>/train/learner beside the actor's .../train/actor (docs/TRACKING.md)."""
    from accrue.tracking import run_name, settings_of, tracking_dir

    name = run_name(ctx.config["workflow"], stage, ctx.step) + "/learner"
    spec = settings_of(getattr(settings, "tracking", None))
    return {"spec": spec, "run_name": name, "log_dir": str(tracking_dir(ctx.store.root, name))}


def link_healthy(link) -> bool:
    """The learner answered a heartbeat within the link's dead_after_s (LearnerLink.healthy())."""
    import time

    healthy = getattr(link, "healthy", None)
    if healthy is not None:
        return bool(healthy())
    return bool(link.ready) and time.monotonic() - link.last_ok < link.dead_after_s


def stop_state(session: HardwareSession, c: dict) -> tuple[bool, str]:
    succ, n = session.window(c["stop_window"])
    rl_time = sum(e["robot_time_s"] for e in session.ordered("train"))
    if n >= c["stop_window"] and succ >= c["stop_successes"]:
        return True, f"stop rule: {succ}/{n} successes over the last {c['stop_window']} episodes"
    if rl_time >= c["budget_s"]:
        return True, f"budget: RL robot time {rl_time:.0f} s >= {c['budget_s']:.0f} s"
    if len(session.ordered("train")) >= c["max_episodes"]:
        return True, f"budget: {c['max_episodes']} episodes"
    return False, ""


def run(ctx: StepContext, settings: SessionSettings) -> None:
    with StopSignals():  # Ctrl-C / SIGTERM: a clean stop (SessionStop), a second one forces
        _run(ctx, settings)


def _run(ctx: StepContext, settings: SessionSettings) -> None:
    from accrue.learner import ReplayBuffer
    from stages.steps.common import learner_config

    c = ctx.config
    task, horizon, seed = c["task_ids"][-1], c["horizon"], c["seed"]
    deterministic(seed)
    cfg = learner_config(dict(c["learner"], device=c["learner"].get("device", "cpu")))
    policy = load_base_policy(ctx.input_path("base-policy"), seed)
    reference = reference_fn(policy, task, horizon)
    features = per_task_features(c, [task])[task]
    warm_dir = ctx.input_path("replay")
    warm = ReplayBuffer.load(warm_dir)
    warm_info = read_json(warm_dir / warmup_step.INFO_FILE)
    handoff = ctx.input_path("handoff") if ctx.has_input("handoff") else None
    session = HardwareSession(ctx, settings)
    try:
        _session(ctx, settings, session, cfg, reference, features, warm_dir, warm, warm_info, handoff)
    except SessionStop as stop:
        raise session.stopped(stop) from None


def _session(ctx, settings, session, cfg, reference, features, warm_dir, warm, warm_info, handoff):
    import torch

    from accrue.learner import begin_stage, end_stage, load_learner, save_learner
    from accrue.robot.episode import replay_from_episodes
    from accrue.robot.learner_client import LearnerLink
    from accrue.robot.learner_service import episode_npz
    from accrue.robot.link_auth import link_auth_for
    from accrue.robot.transport import tar_dir
    from stages.steps.common import copy_tree

    c = ctx.config
    k, tasks, horizon, seed = c["stage"], c["task_ids"], c["horizon"], c["seed"]
    task = tasks[-1]
    if not (session.dir / "learner.json").is_file():  # Algorithm 1 line 1, once per stage
        prev = load_learner(handoff / handoff_step.LEARNER_DIR, device=cfg.device) if handoff else None
        learner = begin_stage(prev, cfg, warm.state_dim, horizon)
        save_learner(learner, session.dir / "learner")
        write_json(session.dir / "learner.json", {"updates": 0, "version": 0, "episodes": []})
        session._save()
    sealed_info = read_json(session.dir / "learner.json")
    acting = {"learner": load_learner(session.dir / "learner", device="cpu"), "version": sealed_info["version"]}
    pending: list[Path] = []  # learner checkpoints to seal, from the link's thread
    lock = threading.Lock()

    def init_payload():
        tmp = ctx.scratch_dir("init")
        for name in ("learner", "warmup", "prior"):  # a re-init after a learner restart starts clean
            if (tmp / name).exists():
                shutil.rmtree(tmp / name)
        copy_tree(session.dir / "learner", tmp / "learner")
        copy_tree(warm_dir, tmp / "warmup")
        if handoff is not None:
            copy_tree(handoff / handoff_step.MEMORY_DIR, tmp / "prior")
        if ctx.has_input("teacher") and (ctx.input_path("teacher") / "teacher.safetensors").is_file():
            shutil.copyfile(ctx.input_path("teacher") / "teacher.safetensors", tmp / "teacher.safetensors")
        info = read_json(session.dir / "learner.json")
        write_json(
            tmp / "init.json",
            {
                "updates": info["updates"],
                "version": info["version"],
                "publish_every": c["publish_every"],
                "checkpoint_every": c["checkpoint_every"],
                "task_index": k - 1,
                "device": cfg.device,
                "torch_threads": 1,
                "tracking": learner_tracking(ctx, settings, k),
            },
        )
        return {}, tar_dir(tmp)

    def sealed_episodes():
        return [
            ({"index": e["index"], "relabel": True}, episode_npz(session.arrays(e["index"])))
            for e in session.ordered("train")
        ]

    def on_snapshot(h: dict, d: Path):
        learner = load_learner(d / "learner", device="cpu")
        with lock:
            acting.update(learner=learner, version=int(h["version"]))
            if h.get("checkpoint"):
                pending.append(d)

    def report(line: str, fields: dict):
        ctx.console.print(f"train: {line}")
        if "event" in fields:
            ctx.log_event(fields.pop("event"), workflow=c["workflow"], stage=k, phase="train", message=line, **fields)

    # a learner on another host is driven with the store's token (or robot.link's); one this actor starts
    # gets a token of its own (LearnerLink's default)
    remote = settings.learner_address is not None
    link = LearnerLink(
        init_payload,
        sealed_episodes,
        on_snapshot,
        report,
        address=settings.learner_address,
        heartbeat_s=settings.heartbeat_s,
        dead_after_s=settings.dead_after_s,
        auth=link_auth_for({"link": settings.link}, ctx.store.root) if remote else None,
        # weights versions stay unique across sessions: the newest one any sealed episode acted with
        version_floor=max([sealed_info["version"], *(e.get("weights_version") or 0 for e in session.ordered())]),
    )
    with children_keep_sigint():  # the learner it spawns is stopped by this actor, not by the terminal
        link.start()
    bridge = make_bridge(c, settings, task, lambda line: report(line, {"event": "robot-fault"}))
    operator = make_operator(settings, bridge, ctx.console, store_root=ctx.store.root, audit=session.audit)
    hold = LearnerHold(lambda: link_healthy(link), settings.hold_staleness_s, settings.hold_wait_s, "train")

    def between():
        with lock:
            todo, pending[:] = list(pending), []
        if todo:
            session.seal_learner(todo[-1])
        succ, n = session.window(c["stop_window"])
        ctx.console.print(
            f"train: {len(session.ordered('train'))} episodes, running success {succ}/{n}, RL robot "
            f"time {sum(e['robot_time_s'] for e in session.ordered('train')):.1f} s, weights "
            f"v{acting['version']}",
            soft_wrap=True,
        )

    def policy_now():
        with lock:
            learner, version = acting["learner"], acting["version"]
        return (lambda s, ref, fresh: learner.act(s, ref, explore=True, reset_mask=fresh)), version

    def on_sealed(index: int, arrays: dict, relabel: bool):
        link.push({"index": index, "relabel": relabel}, episode_npz(arrays))

    reached = stop_state(session, c)
    try:
        episode_loop(
            ctx,
            session,
            operator,
            bridge,
            task=task,
            done=lambda: stop_state(session, c)[0],
            policy_now=policy_now,
            reference=reference,
            features=features,
            settings=episode_settings(c, task, settings.clock),
            gamma=cfg.gamma,
            index_base=int(warm_info["next_episode"]),
            metadata={"task_id": task, "stage": k, "phase": "train", "policy": "base+actor"},
            on_sealed=on_sealed,
            between=between,
            learner_state=lambda: {
                "learner_version": acting["version"],
                "learner_health": "ok" if link_healthy(link) else "lost",
            },
            hold=hold,
        )
        done, why = stop_state(session, c)
        release_robot(bridge, session)  # nothing more to do on the robot while the learner catches up
        operator.tell(f"stopped ({why}); waiting for the learner's last updates")
        target = update_target(session, cfg)
        final_weights(link, target, c["publish_every"], settings.handoff_wait_s)
        snap = link.tmp / f"v{link.version}"
        if snap.is_dir():  # the final snapshot, or (the learner gone) the newest weights this actor received
            session.seal_learner(snap)
        shortfall(ctx, session, target, settings.handoff_wait_s)
        session.close(why or reached[1])
    except BaseException as exc:
        with lock:
            todo = list(pending)
        if todo and not getattr(exc, "forced", False):
            with contextlib.suppress(Exception):  # the newest learner checkpoint received is kept too
                session.seal_learner(todo[-1])
        raise
    finally:
        link.close()
        release_robot(bridge, session)
        operator.close()
    ctx.console.print(f"train: stopped - {why}")

    torch.manual_seed(seed)
    learner = load_learner(session.dir / "learner", device="cpu")
    end_stage(learner)
    out = ctx.new_output("checkpoint", "checkpoint")
    save_learner(learner, out / train_step.LEARNER_DIR)
    info = read_json(session.dir / "learner.json")
    train_eps = session.ordered("train")
    write_json(
        out / train_step.CHECKPOINT_FILE,
        {
            "stage": k,
            "task_ids": tasks,
            "method": cfg.method,
            "per_task": [],
            "updates": info["updates"],
            "update_target": info.get("update_target"),
            "updates_short": info.get("updates_short", 0),
            "episodes": len(train_eps),
            "hardware": True,
        },
    )
    buffer = replay_from_episodes(warm, [session.arrays(e["index"]) for e in train_eps], k - 1)
    buffer.save_new_shards(ctx.new_output("replay", "replay"))
    write_json(ctx.new_output("curve", "eval") / "curve.json", curve_json(c, session, warm_info, why, info))
    episodes_output(ctx, session)


def curve_json(c: dict, session: HardwareSession, warm_info: dict, why: str, learner_info: dict) -> dict:
    """Fig. 4's data: each RL episode's label and cumulative robot time, the window and the stop rule."""
    rows, t, reached = [], 0.0, None
    labels: list[bool] = []
    for e in session.ordered("train"):
        t += e["robot_time_s"]
        labels.append(bool(e["label"]["success"]))
        window = labels[-c["stop_window"] :]
        rows.append(
            {
                "index": e["index"],
                "success": labels[-1],
                "robot_time_s": e["robot_time_s"],
                "cum_robot_time_s": round(t, 6),
                "window_success": sum(window),
                "window_size": len(window),
                "weights_version": e.get("weights_version"),
                "end": e["end"],
                "label_by": e["label"]["by"],
            }
        )
        if reached is None and len(window) >= c["stop_window"] and sum(window) >= c["stop_successes"]:
            reached = round(t, 6)
    return {
        "stage": c["stage"],
        "task_ids": c["task_ids"],
        "hardware": True,
        "method": c["learner"]["method"],
        "seed": c["seed"],
        "episodes": rows,
        "stop_window": c["stop_window"],
        "stop_successes": c["stop_successes"],
        "reached_robot_time_s": reached,
        "stopped": why,
        "rl_robot_time_s": round(t, 6),
        "warmup_robot_time_s": warm_info.get("robot_time_s", 0.0),
        "warmup_episodes": warm_info.get("episodes", 0),
        "updates": learner_info["updates"],
        "train_episodes": len(rows),
        "train_successes": sum(labels),
        "sessions": session.sessions,
    }


STEP = StepDef(
    name="train",
    code_version="hw-train-2",
    run=lambda ctx: run(ctx, SessionSettings()),
    inputs=("base-policy", "replay"),
    optional_inputs=("handoff", "teacher"),
    outputs={"checkpoint": "checkpoint", "replay": "replay", "curve": "eval", "episodes": "episodes"},
    description="asynchronous actor (robot) and learner (process) with operator labels; stops at 19/20",
)
