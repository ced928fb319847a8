"""Issue 21 item 6: the replay's `intervention` column (lerobot HIL-SERL's `is_intervention`).

A transition whose chunk the operator drove (any of its control steps) is flagged in the learner's replay:
built from episodes, kept by save/load, select, concat and the retained-memory handoff, counted by the
learner service. A shard holds the column only where one of its rows is set, so a replay without
interventions (every simulator replay) is byte for byte what it was before the column existed."""

from __future__ import annotations

import hashlib

import numpy as np
import pytest
import torch

from accrue.learner import ReplayBuffer
from accrue.stage_rl import hand_over

D, H, A = 5, 3, 2

# the shards of `no_interventions()` as written before the column existed (accrue at 5b35781, safetensors
# from uv.lock): the column must not change a byte of a replay without interventions
GOLDEN = {
    "index.json": "8737215971d8b08ea07b63abaf88a75205b5b9f9ad6d3617a8fb7e89fb8c3c62",
    "shard-0000000000-0000000007.safetensors": "e1ade06a8fb7afce6dc02c86c17168bdbc665a37b4e1665bef9c6a714c44afa7",
}
OLD_FIELDS = {"state", "action", "ref", "reward", "next_state", "next_ref", "done", "task", "episode", "ended"}


def add_episode(buf: ReplayBuffer, episode: int, n: int, task: int = 2, intervention=None, success=None) -> None:
    s = torch.arange(n * D, dtype=torch.float32).view(n, D) + 10 * episode
    a = buf.action_dim
    chunk = torch.arange(n * H * a, dtype=torch.float32).view(n, H, a) / 7.0 + episode
    done = torch.zeros(n, dtype=torch.bool)
    done[-1] = episode == 0 if success is None else success
    ended = torch.zeros(n, dtype=torch.bool)
    ended[-1] = True
    reward = torch.arange(n, dtype=torch.float32) / 3
    buf.add(s, chunk, -chunk, reward, s + 1, chunk * 0.5, done, task, episode, ended=ended, intervention=intervention)


def no_interventions() -> ReplayBuffer:
    buf = ReplayBuffer(D, H, A, initial_capacity=2)
    add_episode(buf, 0, 4)
    add_episode(buf, 1, 3)
    return buf


def digests(directory) -> dict[str, str]:
    return {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(directory.iterdir())}


def shard_keys(path) -> set[str]:
    from safetensors import safe_open

    with safe_open(str(path), "pt") as f:
        return set(f.keys())


def flags(buf: ReplayBuffer) -> list[bool]:
    return buf.column("intervention").tolist()


def test_a_replay_without_interventions_writes_the_same_bytes_as_before_the_column(tmp_path):
    buf = no_interventions()
    assert flags(buf) == [False] * 7  # every row has the column, all False
    buf.save_new_shards(tmp_path / "r")
    assert digests(tmp_path / "r") == GOLDEN
    [shard] = (tmp_path / "r").glob("shard-*")
    assert shard_keys(shard) == OLD_FIELDS
    # an old replay (no column) loads with the column all False
    assert flags(ReplayBuffer.load(tmp_path / "r")) == [False] * 7


def test_the_column_survives_save_load_and_only_its_shards_hold_it(tmp_path):
    buf = ReplayBuffer(D, H, A)
    add_episode(buf, 0, 4, intervention=torch.tensor([False, True, True, False]))
    buf.save_new_shards(tmp_path / "r")  # shard 1: rows 0-3, two flagged
    add_episode(buf, 1, 3)
    buf.save_new_shards(tmp_path / "r")  # shard 2: rows 4-6, none flagged
    add_episode(buf, 2, 2, intervention=np.array([False, True]))
    buf.save_new_shards(tmp_path / "r")  # shard 3: rows 7-8, row 8 flagged
    want = [False, True, True, False, False, False, False, False, True]
    assert flags(buf) == want
    shards = sorted((tmp_path / "r").glob("shard-*"))
    assert [shard_keys(p) - OLD_FIELDS for p in shards] == [{"intervention"}, set(), {"intervention"}]

    loaded = ReplayBuffer.load(tmp_path / "r")
    assert flags(loaded) == want
    for name in ("state", "action", "reward", "done", "episode", "ended"):
        assert torch.equal(loaded.column(name), buf.column(name)), name
    # a re-save elsewhere reproduces every shard byte for byte, the flagged ones too
    loaded.save_new_shards(tmp_path / "again")
    assert digests(tmp_path / "again") == digests(tmp_path / "r")
    # sampled batches carry the flag of their rows
    batch = loaded.sample(64, torch.Generator().manual_seed(0))
    assert torch.equal(batch.intervention, loaded.column("intervention")[batch.index])


def test_select_concat_and_the_retained_memory_keep_the_flags(tmp_path):
    prior = ReplayBuffer(D, H, A)
    add_episode(prior, 0, 2, task=0, intervention=torch.tensor([True, False]))
    current = ReplayBuffer(D, H, A)
    add_episode(current, 5, 3, task=1, intervention=torch.tensor([False, False, True]))
    add_episode(current, 6, 2, task=1)
    add_episode(current, 7, 3, task=1, intervention=torch.tensor([True, True, False]))
    assert flags(ReplayBuffer.concat([prior, current])) == [True, False] + [False, False, True] + [False] * 2 + [
        True,
        True,
        False,
    ]
    assert flags(current.select(torch.tensor([7, 2, 0]))) == [False, True, False]

    # B^{<k+1} = B^{<k} ∪ the last 2 complete episodes of B^k (6 and 7): through the handoff's save/load
    prior.save_new_shards(tmp_path / "prior")
    memory, report = hand_over(ReplayBuffer.load(tmp_path / "prior"), current, 2)
    assert report["kept"] == {"0": 1, "1": 2}
    assert memory.column("episode").tolist() == [0, 0, 6, 6, 7, 7, 7]
    assert flags(memory) == [True, False, False, False, True, True, False]
    memory.save_new_shards(tmp_path / "memory")
    assert flags(ReplayBuffer.load(tmp_path / "memory")) == flags(memory)


def episode_arrays(episode: int, steps: list[int], marked: list[tuple[int, int]]) -> dict:
    """One episode's transitions as run_episode/transitions leave them, the teleop driving `marked` (chunk,
    control step) pairs; the last chunk may be short."""
    T = len(steps)
    rng = np.random.default_rng(episode)
    marks = np.zeros((T, H), dtype=bool)
    for i, h in marked:
        marks[i, h] = True
    done = np.zeros(T, dtype=bool)
    ended = np.zeros(T, dtype=bool)
    ended[-1] = True
    return {
        "s": rng.normal(size=(T + 1, D)).astype(np.float32),
        "ref": rng.normal(size=(T + 1, H, 6)).astype(np.float32),
        "action": rng.normal(size=(T, H, 6)).astype(np.float32),
        "steps": np.array(steps, dtype=np.int64),
        "reward": np.zeros(T, dtype=np.float32),
        "done": done,
        "ended": ended,
        "episode": np.array(episode, dtype=np.int64),
        "intervention": marks,
    }


def test_replay_from_episodes_flags_the_chunks_the_operator_drove():
    from accrue.robot.episode import intervention_rows, replay_from_episodes

    warm = ReplayBuffer(D, H)
    add_episode(warm, 0, 2, task=0)  # warmup rows first: none driven
    episodes = [
        episode_arrays(3, [3, 3, 3, 1], [(0, 2), (1, 0), (1, 1)]),  # chunks 0 and 1
        episode_arrays(4, [3, 3], []),
        episode_arrays(5, [3, 3, 2], [(2, 1)]),  # the short last chunk only
    ]
    off = episode_arrays(6, [3], [])
    del off["intervention"]  # an episode recorded with interventions off
    buf = replay_from_episodes(warm, [*episodes, off], 0)
    want = [False, False] + [True, True, False, False] + [False, False] + [False, False, True] + [False]
    assert flags(buf) == want
    assert intervention_rows([*episodes, off]).tolist() == want[2:]


def test_the_learner_service_counts_the_driven_transitions():
    from accrue.robot.learner_service import LearnerService, episode_npz

    service = LearnerService()
    try:
        service.run_id, service.info = "run", {"task_index": 0}
        service.warm = ReplayBuffer(D, H)
        add_episode(service.warm, 0, 2, task=0)
        service.episode({"run_id": "run", "index": 3}, episode_npz(episode_arrays(3, [3, 3, 3], [(0, 0), (2, 2)])))
        service.episode({"run_id": "run", "index": 4}, episode_npz(episode_arrays(4, [3, 3], [(1, 1)])))
        service._rebuild()
        answer, _ = service.heartbeat({}, b"")
        assert answer["intervention_transitions"] == 3 and answer["episodes"] == 2
        # a re-label replaces the episode's rows: now undriven
        service.episode({"run_id": "run", "index": 4, "relabel": True}, episode_npz(episode_arrays(4, [3, 3], [])))
        service._rebuild()
        assert service.heartbeat({}, b"")[0]["intervention_transitions"] == 2
    finally:
        service.remove_tmp()


@pytest.mark.parametrize("bad", [torch.zeros(3, dtype=torch.bool), torch.zeros((4, 2), dtype=torch.bool)])
def test_a_misshapen_flag_is_refused(bad):
    from accrue.errors import AccrueError

    with pytest.raises(AccrueError, match="intervention has shape"):
        add_episode(ReplayBuffer(D, H, A), 0, 4, intervention=bad)
