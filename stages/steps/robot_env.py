"""A robot as the environment of warmup, train and evaluate-all (paper Sec. V-C): operator-labelled
episodes at the control rate (real-time pacing by the session's clock), each sealed at once
(stages.steps.robot_session), resumable with `--continue` across days.

- warmup: π_base^k alone for `episodes` episodes; their chunk transitions are B^k's first shard, their
  robot time reported apart from RL's (Fig. 4's shaded warmup).
- train: an asynchronous actor (this process, on the robot) and learner (another process, here or on a
  GPU host, over gRPC), stopping when the running success over the last `stop_window` episodes reaches
  `stop_successes` (19/20) or the robot-time budget is spent. Every `checkpoint_every` learner updates
  are sealed too; `--continue` reloads the last learner checkpoint and every sealed episode.
- evaluate-all: `trials` retention trials of π_base^k + θ^k on each earlier task (paper Table III); the
  current task's figure is its training window.

What the steps read (stages.steps.stage_io) and write (their modules) is the simulator's; the robot's
outputs add `episodes` (every sealed episode's record and MCAP log, the sessions) and "hardware": true.
"""

from __future__ import annotations

import contextlib
import shutil
import threading
from pathlib import Path

from stages.errors import StageError
from stages.runner_context import StepContext
from stages.steps.common import Progress, copy_tree, read_json, write_json
from stages.steps.robot_session import (
    EpisodeLoop,
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
from stages.steps.stage_io import (
    BaseInputs,
    Deployed,
    EvaluateResult,
    Inherited,
    TrainResult,
    Warmup,
    WarmupResult,
    tracking_run,
)

# the robot steps' own code versions (their caches are not the simulator's: stages.steps.robot_plan.bind_robot)
CODE_VERSIONS = {"warmup": "hw-warmup-1", "train": "hw-train-2", "evaluate-all": "hw-evaluate-all-1"}


def episode_settings(c: dict, task: str, clock: float):
    from accrue.robot.bridge import ResetPose
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
        reset=ResetPose.from_dict(r.get("reset_pose")),
    )


def robot_layout(mapping) -> dict:
    """What the learner's s and a are made of on this robot: its action keys (d, the chunks' width) and the
    cameras whose E(I) is in s, in order. The replay, the learner and the checkpoint carry it."""
    return {"action_keys": list(mapping.action_keys), "cameras": list(mapping.camera_keys)}


def check_layout(inherited: dict, current: dict, stage: int) -> None:
    """One line when stage `stage` acts in other action keys or reads other cameras than the learner it
    inherits was trained on (its chunks' width and its s would not fit)."""
    if not inherited or not current or inherited == current:
        return

    def text(layout: dict) -> str:
        keys, cams = layout.get("action_keys", []), layout.get("cameras", [])
        return f"{len(keys)} action keys ({', '.join(keys)}) and cameras [{', '.join(cams)}]"

    raise StageError(
        f"train: stage {stage}'s robot has {text(current)}, and the learner it inherits was trained on "
        f"{text(inherited)}: a stage cannot change them (set robot.action_keys / robot.camera_keys as before, "
        "or start a new workflow)"
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


def learner_tracking(ctx: StepContext, tracking: dict | None, settings: SessionSettings, stage: int) -> dict:
    """What the learner needs to write its scalars (accrue.robot.learner_service): the run the plan bound to
    train (stages.steps.stage_io.tracking_run, as the simulator's train; unbound, the session's tracking
    section) with /learner after it, beside the actor's (docs/TRACKING.md)."""
    from accrue.tracking import settings_of

    spec, name, log_dir = tracking_run(ctx, tracking or {"spec": settings.tracking}, stage, ctx.config["workflow"])
    return {"spec": settings_of(spec), "run_name": name + "/learner", "log_dir": str(log_dir / "learner")}


def learner_before_warmup(ctx: StepContext, settings: SessionSettings, poll_s: float = 1.0) -> None:
    """Before the robot's first warmup episode: a learner on another host (robot.learner_address) answers
    Hello with the link token, or nothing moves - waited for up to robot.hold.wait_s, then one line saying it
    never answered (why: a name that does not resolve, nothing listening, no answer), or at once one saying
    what to fix when it refuses this actor (its token, TLS). A learner this actor starts itself is started
    now, in the background, when train follows in this process (learner_client.start_learner_ahead), so
    that it is up when train's first episode begins."""
    import time

    from accrue.robot import learner_client
    from accrue.robot.link_auth import link_auth_for
    from accrue.robot.transport import PROTOCOL, LinkRefused, Peer, PeerDown

    address = settings.learner_address
    if address is None:
        if learner_client.learner_ahead():
            learner_client.prestart_learner(settings.dead_after_s)
        return
    auth = link_auth_for({"link": settings.link}, ctx.store.root)
    peer = Peer(address, auth.token, tls_ca=auth.tls_ca)
    deadline, told = time.monotonic() + settings.hold_wait_s, False
    try:
        while True:
            try:
                peer.call("Hello", {"protocol": PROTOCOL}, timeout=3.0)
                break
            except LinkRefused as exc:
                raise StageError(f"warmup: {learner_client.refusal_line(address, exc, auth)}; nothing moved") from None
            except PeerDown as exc:
                if time.monotonic() >= deadline:
                    raise StageError(
                        f"warmup: the learner at {address} never answered within robot.hold.wait_s "
                        f"{settings.hold_wait_s:g} s (last try: {exc}); nothing moved: start it (`accrue robot "
                        "learner ...` on its host, docs/ROBOT_LINK.md) and run again"
                    ) from None
                if not told:
                    ctx.console.print(
                        f"warmup: waiting for the learner at {address} before the robot's first episode ({exc}); "
                        f"up to robot.hold.wait_s {settings.hold_wait_s:g} s",
                        soft_wrap=True,
                    )
                    told = True
                time.sleep(poll_s)
    finally:
        peer.close()
    if told:
        ctx.console.print(f"warmup: the learner at {address} answered; going on")


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
        "hardware": True,
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


def classifier_gate(c: dict, session: HardwareSession):
    """robot.success_classifier's gate for warmup and train (keyed in their configs only when enabled);
    None for evaluate-all, whose retention trials stay the operator's to grade, and when it is off."""
    spec = c.get("success_classifier")
    if not spec or not spec.get("enabled") or c["phase"] not in ("warmup", "train"):
        return None
    from accrue.robot.success_classifier import ClassifierSettings
    from stages.steps.robot_classifier import ClassifierGate

    return ClassifierGate(ClassifierSettings.from_dict(spec), session, c["encoder"], c["phase"])


class _Current:
    """The bridge of the task being evaluated, for an operator that outlives each task's bridge."""

    bridge = None

    def hook(self, name: str):
        return self.bridge.hook(name) if self.bridge is not None else None


class RobotEnvironment:
    def __init__(self, settings: SessionSettings | None = None):
        self.settings = settings or SessionSettings()
        self.classifier = None  # robot.success_classifier's gate for the step's session (warmup, train)
        self.session: HardwareSession | None = None  # the step's, once opened (scope() tells a stop with it)

    @contextlib.contextmanager
    def scope(self, ctx: StepContext):
        """Ctrl-C / SIGTERM while the step runs: a clean stop (SessionStop), a second one forces. Wherever
        it comes - reading the inputs, in the session, writing the outputs - its one line says what is
        sealed and how to resume."""
        self.session = None
        with StopSignals():
            try:
                yield
            except SessionStop as stop:
                raise self._stopped(ctx, stop) from None

    def _stopped(self, ctx: StepContext, stop: SessionStop) -> SessionStop:
        if self.session is not None:  # the episode in progress discarded, the session closed
            return self.session.stopped(stop)
        return SessionStop(
            f"{ctx.step}: {stop.how}{' (forced)' if stop.forced else ''}; before its session opened "
            f"(resume with `accrue stage run ... --step {ctx.step} --continue`)",
            stop.how,
            stop.code,
            stop.forced,
        )

    def learner_device(self) -> str:
        return "cpu"  # not pinned by the workflow: the actor acts on CPU (the learner's device is its own)

    @contextlib.contextmanager
    def _session(self, ctx: StepContext):
        """The step's session; a stop in it, or after it while the step writes its outputs, is told by
        scope() with this session's count of sealed episodes."""
        self.session = HardwareSession(ctx, self.settings)
        self.classifier = classifier_gate(ctx.config, self.session)
        if self.classifier is not None:
            from stages.steps.robot_classifier import CARRIED

            if ctx.has_input(CARRIED):  # train starts from what the operator taught warmup (this stage's)
                self.classifier.carry(ctx.input_path(CARRIED), ctx.inputs[CARRIED])
        yield self.session

    def _fault(self, ctx: StepContext):
        return lambda line: ctx.log_event("robot-fault", message=line, stage=ctx.config["stage"])

    # ------------------------------------------------------------------ warmup (Algorithm 1 line 3)
    def warmup(self, ctx: StepContext, base: BaseInputs, buffer) -> WarmupResult:
        import numpy as np

        from accrue import rl_loop
        from accrue.robot.episode import replay_from_episodes

        c, settings = ctx.config, self.settings
        task, k = c["task"], c["stage"]
        features = base.features[task]
        learner_before_warmup(ctx, settings)
        with self._session(ctx) as session:
            bridge = make_bridge(c, settings, task, self._fault(ctx))
            operator = make_operator(settings, bridge, ctx.console, store_root=ctx.store.root, audit=session.audit)
            # a line per sealed episode, with the rate and time left (an operator's episodes take minutes)
            progress = Progress(  # an earlier session's episodes are not this one's rate
                ctx.console.print, "warmup", unit="episode", parts=max(1, c["episodes"]), base=len(session.episodes)
            )
            try:
                loop = EpisodeLoop(
                    task=task,
                    done=lambda: len(session.episodes) >= c["episodes"],
                    on_sealed=lambda index, arrays, relabel=False: progress(len(session.episodes), c["episodes"]),
                    policy_now=lambda: (rl_loop.execute_reference, None),
                    reference=base.references[task],
                    features=features,
                    settings=episode_settings(c, task, settings.clock),
                    gamma=c["gamma"],
                    index_base=0,
                    metadata={"task_id": task, "stage": k, "phase": "warmup", "policy": "base"},
                    classifier=self.classifier,
                )
                episode_loop(ctx, session, operator, bridge, loop)
                session.close(f"{c['episodes']} warmup episodes")
            finally:
                release_robot(bridge, session)
                operator.close()
            eps = session.ordered()
            arrays = [session.arrays(e["index"]) for e in eps]
            # s's width from an episode that executed a chunk (one a fault ended before its first has no s rows)
            widths = [a["s"].shape[-1] for a in arrays if len(a["action"])]
            dim = widths[0] if widths else features({"state": np.zeros((1, 29), np.float32)}).shape[1]
            mapping = bridge.mapping  # bound to the robot's features when it connected
            bound = mapping.state_keys is not None
            d = mapping.action_dim if bound else next((a["action"].shape[-1] for a in arrays if len(a["action"])), 6)
            replay = replay_from_episodes(buffer(dim, d), arrays, k - 1)
            replay.layout = robot_layout(mapping) if bound else {}
            labels = [bool(e["label"]["success"]) for e in eps]
            episodes_output(ctx, session)
            if self.classifier is not None:
                self.classifier.write_output(ctx)
            return WarmupResult(
                replay,
                len(eps),
                sum(labels),
                sum(e["control_steps"] for e in eps),
                max([e["index"] for e in eps], default=-1) + 1,
                {
                    "hardware": True,
                    "robot_time_s": round(session.robot_time_s(), 6),
                    "episode_robot_time_s": [e["robot_time_s"] for e in eps],
                    "labels": labels,
                },
                f"warmup: {len(eps)} base-policy episodes on the robot ({task}), {sum(labels)} labelled success, "
                f"robot time {session.robot_time_s():.1f} s",
            )

    # ------------------------------------------------------------------ train (Algorithm 1 lines 4-10)
    def train(
        self, ctx: StepContext, cfg, base: BaseInputs, warm: Warmup, inherited: Inherited, tracking
    ) -> TrainResult:
        """The actor here, the learner in its own process (`tracking`: the run the plan bound, where the
        learner writes its scalars; the actor's, each sealed episode's, follow SessionSettings.tracking)."""
        warm_buffer = warm.buffer()
        with self._session(ctx) as session:
            why = self._train(ctx, session, cfg, base, warm, warm_buffer, inherited, tracking)
            return self._trained(ctx, session, warm, warm_buffer, inherited, why)

    def _trained(self, ctx, session, warm, warm_buffer, inherited, why) -> TrainResult:
        import torch

        from accrue.learner import end_stage, load_learner
        from accrue.robot.episode import replay_from_episodes

        c = ctx.config
        ctx.console.print(f"train: stopped - {why}")

        torch.manual_seed(c["seed"])
        learner = load_learner(session.dir / "learner", device="cpu")
        end_stage(learner)
        info = read_json(session.dir / "learner.json")
        train_eps = session.ordered("train")
        buffer = replay_from_episodes(warm_buffer, [session.arrays(e["index"]) for e in train_eps], c["stage"] - 1)
        episodes_output(ctx, session)
        if self.classifier is not None:
            self.classifier.write_output(ctx)
        return TrainResult(
            learner,
            buffer,
            inherited.per_task,  # Isolated: the learners kept for tasks 1..k-1 go on (handoff adds task k's)
            {
                "updates": info["updates"],
                "update_target": info.get("update_target"),
                "updates_short": info.get("updates_short", 0),
                "episodes": len(train_eps),
                "hardware": True,
                **({"layout": learner.layout} if learner.layout else {}),
            },
            curve_json(c, session, warm.info, why, info),
        )

    def _train(self, ctx, session, cfg, base, warm, warm_buffer, inherited, tracking) -> str:
        from accrue.learner import begin_stage, load_learner, save_learner
        from accrue.robot.learner_client import LearnerLink
        from accrue.robot.learner_service import episode_npz
        from accrue.robot.link_auth import link_auth_for
        from accrue.robot.transport import tar_dir

        c, settings = ctx.config, self.settings
        k, tasks, horizon = c["stage"], c["task_ids"], c["horizon"]
        task = tasks[-1]
        if not (session.dir / "learner.json").is_file():  # Algorithm 1 line 1, once per stage
            previous = inherited.previous(cfg.device)
            if previous is not None:  # before the robot moves: the chunks' width and s must fit θ^{k-1}
                check_layout(previous.layout, warm_buffer.layout, k)
            learner = begin_stage(previous, cfg, warm_buffer.state_dim, horizon, warm_buffer.action_dim)
            learner.layout = dict(warm_buffer.layout)
            save_learner(learner, session.dir / "learner")
            write_json(session.dir / "learner.json", {"updates": 0, "version": 0, "episodes": []})
            session._save()
        sealed_info = read_json(session.dir / "learner.json")
        acting = {
            "learner": load_learner(session.dir / "learner", device="cpu"),
            "version": sealed_info["version"],
            "updates": sealed_info["updates"],
        }
        pending: list[Path] = []  # learner checkpoints to seal, from the link's thread
        lock = threading.Lock()

        def init_payload():
            """B^k's warmup shard, B^{<k} and the cached targets travel to the learner, which loads them."""
            tmp = ctx.scratch_dir("init")
            for name in ("learner", "warmup", "prior"):  # a re-init after a learner restart starts clean
                if (tmp / name).exists():
                    shutil.rmtree(tmp / name)
            copy_tree(session.dir / "learner", tmp / "learner")
            copy_tree(warm.dir, tmp / "warmup")
            if inherited.memory_dir is not None:
                copy_tree(inherited.memory_dir, tmp / "prior")
            if inherited.teacher_file is not None:
                shutil.copyfile(inherited.teacher_file, tmp / "teacher.safetensors")
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
                    "tracking": learner_tracking(ctx, tracking, settings, k),
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
                acting.update(learner=learner, version=int(h["version"]), updates=int(h.get("updates", 0)))
                if h.get("checkpoint"):
                    pending.append(d)

        def report(line: str, fields: dict):
            ctx.console.print(f"train: {line}")
            if "event" in fields:
                ctx.log_event(
                    fields.pop("event"), workflow=c["workflow"], stage=k, phase="train", message=line, **fields
                )

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
        hold = LearnerHold(
            lambda: link_healthy(link),
            settings.hold_staleness_s,
            settings.hold_wait_s,
            "train",
            refused=lambda: getattr(link, "refused", None),  # a LearnerLink's LinkRefused (its token, TLS)
            # a learner this actor starts itself is given its start-up before the robot's first action
            first_wait_s=0.0 if remote else float(getattr(link, "start_timeout_s", 0.0)),
            learner=f"the learner at {settings.learner_address}"
            if remote
            else "the learner process this actor started",
            last_error=lambda: getattr(link, "last_error", None),
        )

        def between():
            with lock:
                todo, pending[:] = list(pending), []
            if todo:
                session.seal_learner(todo[-1])
            succ, n = session.window(c["stop_window"])
            ctx.console.print(
                f"train: {len(session.ordered('train'))} episodes, running success {succ}/{n}, RL robot "
                f"time {sum(e['robot_time_s'] for e in session.ordered('train')):.1f} s of "
                f"{c['budget_s']:g} s, weights v{acting['version']} ({acting['updates']} learner updates)",
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
            loop = EpisodeLoop(
                task=task,
                done=lambda: stop_state(session, c)[0],
                policy_now=policy_now,
                reference=base.references[task],
                features=base.features[task],
                settings=episode_settings(c, task, settings.clock),
                gamma=cfg.gamma,
                index_base=int(warm.info["next_episode"]),
                metadata={"task_id": task, "stage": k, "phase": "train", "policy": "base+actor"},
                on_sealed=on_sealed,
                between=between,
                learner_state=lambda: {
                    "learner_version": acting["version"],
                    "learner_health": "ok" if link_healthy(link) else "lost",
                },
                hold=hold,
                classifier=self.classifier,
            )
            episode_loop(ctx, session, operator, bridge, loop)
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
        return why

    # ------------------------------------------------------------------ evaluate-all (Table III)
    def evaluate(self, ctx: StepContext, base: BaseInputs, deployed: Deployed) -> EvaluateResult:
        from accrue import rl_loop

        c, settings = ctx.config, self.settings
        k, tasks, n = c["stage"], c["task_ids"], c["trials"]
        with self._session(ctx) as session:
            current = _Current()  # one operator (one page) for every task's bridge
            operator = None
            for i, task in enumerate(tasks[:-1]):
                mine = lambda t=task: [e for e in session.ordered() if e["task"] == t]  # noqa: E731
                if len(mine()) >= n:
                    continue
                bridge = current.bridge = make_bridge(c, settings, task, self._fault(ctx))
                if operator is None:
                    operator = make_operator(
                        settings, current, ctx.console, store_root=ctx.store.root, audit=session.audit
                    )
                operator.tell(f"retention trials on task {i + 1} ({task}): set up its parts")
                try:
                    loop = EpisodeLoop(
                        task=task,
                        done=lambda mine=mine: len(mine()) >= n,
                        # the deterministic actor the method deploys for this task (Isolated: task i's own)
                        policy_now=lambda act=rl_loop.actor_act(deployed.learners[task]): (act, None),
                        reference=base.references[task],
                        features=base.features[task],
                        settings=episode_settings(c, task, settings.clock),
                        gamma=c["gamma"],
                        index_base=0,
                        metadata={"task_id": task, "stage": k, "phase": "evaluate", "policy": "base+actor"},
                    )
                    episode_loop(ctx, session, operator, bridge, loop)
                except BaseException:
                    operator.close()
                    raise
                finally:
                    release_robot(bridge, session)
            if operator is not None:
                operator.close()
            session.close("retention trials done")
            trials = {t: [bool(e["label"]["success"]) for e in session.ordered() if e["task"] == t] for t in tasks[:-1]}
            episodes_output(ctx, session)
            for t, v in trials.items():
                ctx.console.print(f"evaluate-all: {t}: {sum(v)}/{len(v)} retention trials succeeded")
            return EvaluateResult(
                {t: sum(v) / len(v) for t, v in trials.items() if v},
                {},
                n,
                {"hardware": True, "trials": trials, "successes": {t: sum(v) for t, v in trials.items()}},
            )
