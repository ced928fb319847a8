"""The actor-learner link over gRPC in one process: a standalone learner (as on a second host) is initialised
by the actor, trains from the episodes pushed to it and serves newer weights; a protocol mismatch is refused
with both versions named; when the learner goes away the actor is told within seconds and keeps its weights,
and a new learner at the same address is re-initialised with every sealed episode."""

from __future__ import annotations

import json
import threading
import time

import numpy as np
import pytest

from accrue.errors import AccrueError
from accrue.robot.link_auth import LinkAuth
from accrue.robot.transport import Peer, serve

TOKEN = "test-link-token"

pytestmark = pytest.mark.timeout(300)


def start_learner(port: int = 0, audit=None, **tls):
    """A standalone learner in this process (as on a second host), checking TOKEN."""
    from accrue.robot.learner_service import LearnerService

    service = LearnerService(audit=audit)
    server, port = serve(service.handlers(), f"127.0.0.1:{port}", token=TOKEN, on_refused=service.on_refused, **tls)
    threading.Thread(target=service.train_forever, daemon=True).start()
    return service, server, port


def init_payload(tmp):
    from accrue.learner import LearnerConfig, ReplayBuffer, make_learner, save_learner
    from accrue.robot.transport import tar_dir
    from stages.steps.common import write_json

    d = tmp / "init"
    cfg = LearnerConfig.from_dict(
        {
            "algo": "fasttd3",
            "actor_hidden": [16],
            "critic_hidden": [16],
            "projector_dim": 8,
            "batch_size": 8,
            "utd": 1,
            "seed": 0,
        }
    )
    save_learner(make_learner(cfg, 29, 4), d / "learner")
    warm = ReplayBuffer(29, 4)
    rng = np.random.default_rng(0)
    warm.add(
        rng.normal(size=(6, 29)),
        np.zeros((6, 4, 6)),
        np.zeros((6, 4, 6)),
        np.zeros(6),
        rng.normal(size=(6, 29)),
        np.zeros((6, 4, 6)),
        np.zeros(6, bool),
        0,
        0,
        ended=np.eye(6, dtype=bool)[-1],
    )
    warm.save_new_shards(d / "warmup")
    write_json(
        d / "init.json",
        {
            "updates": 0,
            "version": 0,
            "publish_every": 2,
            "checkpoint_every": 4,
            "task_index": 0,
            "device": "cpu",
            "torch_threads": 1,
        },
    )
    return {}, tar_dir(d)


def episode(index: int, chunks: int = 5):
    from accrue.robot.learner_service import episode_npz

    rng = np.random.default_rng(index)
    return episode_npz(
        {
            "s": rng.normal(size=(chunks + 1, 29)).astype(np.float32),
            "ref": np.zeros((chunks + 1, 4, 6), np.float32),
            "action": np.zeros((chunks, 4, 6), np.float32),
            "steps": np.full(chunks, 4),
            "reward": np.zeros(chunks, np.float32),
            "done": np.zeros(chunks, bool),
            "ended": np.eye(chunks, dtype=bool)[-1],
            "episode": np.array(index),
        }
    )


def wait_for(check, timeout, what):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if check():
            return
        time.sleep(0.05)
    raise AssertionError(f"timed out waiting for {what}")


def test_link_trains_serves_weights_and_survives_a_learner_restart(tmp_path, one_torch_thread):
    from accrue.robot.learner_client import LearnerLink

    service, server, port = start_learner()
    with pytest.raises(AccrueError, match="protocol mismatch: actor speaks 99"):
        Peer(f"127.0.0.1:{port}", TOKEN).call("Hello", {"protocol": 99})
    sealed: list[tuple[dict, bytes]] = []
    snapshots, reports = [], []
    link = LearnerLink(
        lambda: init_payload(tmp_path),
        lambda: list(sealed),
        lambda h, d: snapshots.append((h["version"], h["updates"], (d / "learner").is_dir())),
        lambda line, fields: reports.append(fields.get("event", line)),
        address=f"127.0.0.1:{port}",
        heartbeat_s=0.1,
        dead_after_s=1.0,
        auth=LinkAuth(TOKEN),
    )
    link.start()
    for i in range(3):
        sealed.append(({"index": i, "relabel": False}, episode(i)))
        link.push(*sealed[-1])
    wait_for(lambda: service.updates >= 15 and snapshots and snapshots[-1][1] >= 10, 120, "training on the episodes")
    assert sorted(service.episodes) == [0, 1, 2]
    versions = [v for v, _, _ in snapshots]
    assert versions == sorted(versions) and all(ok for _, _, ok in snapshots)

    # the learner goes away: reported within seconds; the actor keeps the weights it has
    server.stop(grace=0)
    service.stop.set()
    have = link.version
    wait_for(lambda: "robot-learner-lost" in reports, 10, "the lost learner to be reported")
    kept = link.version  # a Pull answered just before the stop can land after `have` was read (seen under load)
    assert kept >= have
    sealed.append(({"index": 3, "relabel": False}, episode(3)))
    link.push(*sealed[-1])
    assert link.version == kept  # no learner: nothing replaces the weights it has

    # a new learner at the same address: re-initialised with every sealed episode, no episode twice
    service2, server2, _ = start_learner(port)
    wait_for(lambda: sorted(service2.episodes) == [0, 1, 2, 3], 120, "the new learner to get every episode")
    wait_for(lambda: "robot-learner-back" in reports, 10, "the actor to say the learner is back")
    assert link.final_snapshot(wait_s=30) and link.version >= 1
    link.close()
    server2.stop(grace=0)
    service2.stop.set()


def test_a_pull_between_any_two_trainer_writes_gets_every_checkpoint_marked(tmp_path, one_torch_thread):
    """Pulls are answered on the server's threads while the trainer publishes (it drops the GIL in file
    calls): an actor pulling between any two of the trainer's writes must still get each checkpoint marked.
    A snapshot visible before its mark went out unmarked, and so did every later one, since the actor then
    held its version: the link never saw the checkpoint at 12 (the restart test's rare timeout)."""
    from accrue.robot.learner_service import LearnerService

    received: list[tuple[int, int, bool]] = []  # version, updates, checkpoint: what the actor was given

    class PulledBetweenWrites(LearnerService):
        probing = False

        def __setattr__(self, name, value):
            super().__setattr__(name, value)
            if self.probing and name != "probing":  # an actor's Pull answered right after this write
                self.probing = False  # the Pull's own writes are not the trainer's
                have = received[-1][0] if received else -1
                h, _ = self.pull({"have": have}, b"")
                if h["version"] is not None:
                    received.append((h["version"], h["updates"], h["checkpoint"]))
                self.probing = True

    service = PulledBetweenWrites()
    header, blob = init_payload(tmp_path)
    service.init(dict(header, run_id="r"), blob)
    for i in range(3):
        service.episode({"index": i, "run_id": "r"}, episode(i))
    service.probing = True
    trainer = threading.Thread(target=service.train_forever, daemon=True)
    trainer.start()
    # 3 episodes x 5 chunks, utd 1: 15 updates, published every 2 (the last at 14), checkpoints at 4, 8, 12
    wait_for(lambda: received and received[-1][1] == 14, 120, "the snapshot at 14")
    service.stop.set()
    trainer.join(timeout=10)
    assert {4, 8, 12, 14} <= {u for _, u, _ in received}  # the actor got each snapshot as it came
    assert [u for _, u, checkpoint in received if checkpoint] == [4, 8, 12], received


def test_weights_that_arrive_after_newer_ones_do_not_replace_them(tmp_path):
    """final_snapshot's Pull (on the actor's thread) and the link thread's Pull can be answered in either
    order: the older answer, landing second, must not take the actor back to older weights (nor untar over
    the snapshot it holds)."""
    from accrue.robot.learner_client import LearnerLink
    from accrue.robot.transport import tar_dir

    def answer(version: int, updates: int) -> tuple[dict, bytes]:
        d = tmp_path / f"snap{version}"
        d.mkdir()
        (d / "learner.json").write_text(json.dumps({"version": version, "updates": updates}))
        return {"version": version, "updates": updates, "checkpoint": False}, tar_dir(d)

    acted: list[int] = []
    link = LearnerLink(lambda: ({}, b""), list, lambda h, d: acted.append(h["version"]), lambda line, fields: None)
    try:
        fresh, late = answer(6, 12), answer(5, 10)  # both asked with have=4; the fresh one is taken first
        link._take(*fresh)
        link._take(*late)
        link._take(*fresh)  # the same weights twice: taken once
        assert (link.version, link.updates, acted) == (6, 12, [6])
    finally:
        link.close()
