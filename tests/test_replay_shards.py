"""Replay buffer: append-only shards save/load exactly, byte-identical re-saves, retention, n-step."""

import json

import pytest
import torch

from accrue.errors import AccrueError
from accrue.learner import ReplayBuffer, retain_last_episodes
from accrue.learner.replay import complete_episodes

D, H, A = 5, 3, 2


def add_rows(buf, n, task, episode, start=0.0, done=None, ended=None):
    s = torch.arange(n * D, dtype=torch.float32).view(n, D) + start
    chunk = torch.full((n, H, A), start / 100.0)
    done = torch.zeros(n, dtype=torch.bool) if done is None else done
    buf.add(
        s,
        chunk,
        -chunk,
        torch.arange(n, dtype=torch.float32) + start,
        s + 1,
        chunk * 0.5,
        done,
        task,
        episode,
        ended=ended,
    )


def same(a: ReplayBuffer, b: ReplayBuffer) -> bool:
    names = ("state", "action", "ref", "reward", "next_state", "next_ref", "done", "task", "episode", "ended")
    return len(a) == len(b) and all(torch.equal(a.column(k), b.column(k)) for k in names)


def test_shards_are_append_only_and_load_exactly(tmp_path):
    buf = ReplayBuffer(D, H, A, initial_capacity=2)
    add_rows(buf, 7, 0, torch.arange(7) // 3)
    first = buf.save_new_shards(tmp_path / "a")
    assert [p.name for p in first] == ["shard-0000000000-0000000007.safetensors"]
    add_rows(buf, 5, 1, 10, start=1000.0)
    second = buf.save_new_shards(tmp_path / "a")
    assert len(second) == 1 and second[0] != first[0]  # only the new rows are written
    assert buf.save_new_shards(tmp_path / "a") == []  # nothing new → nothing written
    index = json.loads((tmp_path / "a" / "index.json").read_text())
    assert index["size"] == 12 and [s["count"] for s in index["shards"]] == [7, 5]

    loaded = ReplayBuffer.load(tmp_path / "a")
    assert same(buf, loaded)
    # re-saving the loaded buffer elsewhere reproduces the earlier shards byte for byte
    loaded.save_new_shards(tmp_path / "b")
    for name in ("shard-0000000000-0000000007.safetensors", "shard-0000000007-0000000005.safetensors"):
        assert (tmp_path / "a" / name).read_bytes() == (tmp_path / "b" / name).read_bytes()
    # and continues appending after them
    add_rows(loaded, 2, 1, 11, start=5000.0)
    loaded.save_new_shards(tmp_path / "b")
    assert same(loaded, ReplayBuffer.load(tmp_path / "b"))


def test_load_reports_missing_or_bad_shards(tmp_path):
    buf = ReplayBuffer(D, H, A)
    add_rows(buf, 3, 0, 0)
    buf.save_new_shards(tmp_path)
    (tmp_path / "shard-0000000000-0000000003.safetensors").unlink()
    with pytest.raises(AccrueError, match="missing"):
        ReplayBuffer.load(tmp_path)
    with pytest.raises(AccrueError, match="not a replay buffer"):
        ReplayBuffer.load(tmp_path / "nowhere")


@pytest.mark.parametrize(
    "damage, message",
    [
        (lambda index, shard: index.update(shards=3), "malformed replay index \\(shard entry"),
        (lambda index, shard: index["shards"][0].pop("file"), "malformed replay index \\(shard entry: 'file'"),
        (lambda index, shard: index["shards"][0].update(count="three"), "malformed replay index \\(shard entry"),
        (lambda index, shard: shard.write_bytes(b"not a safetensors file"), "corrupt replay shard"),
    ],
    ids=["shards-not-a-list", "entry-without-file", "count-not-a-number", "shard-file-garbage"],
)
def test_a_damaged_replay_directory_is_one_accrue_error_not_a_bare_exception(tmp_path, damage, message):
    """Found by the mutation triage of replay.py: the shard entries and the shard files were read outside
    the index's error handling, so these raised TypeError / KeyError / SafetensorError (a CLI traceback)."""
    buf = ReplayBuffer(D, H, A)
    add_rows(buf, 3, 0, 0)
    buf.save_new_shards(tmp_path)
    index_path = tmp_path / "index.json"
    index = json.loads(index_path.read_text())
    damage(index, tmp_path / "shard-0000000000-0000000003.safetensors")
    index_path.write_text(json.dumps(index))
    with pytest.raises(AccrueError, match=message):
        ReplayBuffer.load(tmp_path)


def test_sampling_is_deterministic_under_a_generator():
    buf = ReplayBuffer(D, H, A)
    add_rows(buf, 50, 0, torch.arange(50) // 5)
    a = buf.sample(16, torch.Generator().manual_seed(3))
    b = buf.sample(16, torch.Generator().manual_seed(3))
    assert torch.equal(a.index, b.index) and torch.equal(a.state, b.state)
    assert torch.equal(a.state, buf.column("state")[a.index])
    with pytest.raises(AccrueError, match="empty"):
        ReplayBuffer(D, H, A).sample(1, torch.Generator())


def test_retain_keeps_the_last_complete_episodes_never_fragments():
    buf = ReplayBuffer(D, H, A)
    # task 0: episodes 0..3 with 2 chunks each, interleaved like parallel envs. Episodes 0-2 end in their
    # second chunk (episode 1 first, then 0, then 2: success and time limit alike); episode 3 is a fragment
    # cut by the budget. Task 1: episode 7 ends, episode 8 is a fragment.
    for ep in range(4):
        add_rows(buf, 1, 0, ep, start=100 * ep)
    for ep in (1, 0, 2, 3):
        add_rows(buf, 1, 0, ep, start=100 * ep + 1, ended=torch.tensor([ep != 3]))
    add_rows(buf, 2, 1, torch.tensor([7, 8]), start=900.0, ended=torch.tensor([True, False]))
    kept = retain_last_episodes(buf, 2)
    pairs = list(zip(kept.column("task").tolist(), kept.column("episode").tolist()))
    # the last two episodes to END are 0 and 2 (whole, in original row order); the fragments never count,
    # even though they were stored last; task 1 has one complete episode and keeps just it
    assert pairs == [(0, 0), (0, 2), (0, 0), (0, 2), (1, 7)]
    assert complete_episodes(buf) == {0: [1, 0, 2], 1: [7]}
    assert len(retain_last_episodes(buf, 0)) == 0
    assert sorted(set(retain_last_episodes(buf, 10).column("episode").tolist())) == [0, 1, 2, 7]


def test_retained_memory_of_a_checkpointed_vec_env_run_holds_only_whole_episodes():
    """64-env shape of the old bug: every env's episode still running at the budget's end was stored last."""
    from accrue import rl_loop
    from accrue.learner_inputs import state_features
    from accrue.sim import make_vec_env
    from accrue.sim.observation import IDX

    env = make_vec_env("nist/rect_peg", num_envs=4, seed=3)
    buf = ReplayBuffer(env.reset()["state"].shape[1], 2, 6)
    collector = rl_loop.ChunkCollector(
        env, lambda obs: torch.zeros(len(obs["state"]), 2, 6).numpy(), state_features, buf, task_index=0, gamma=0.99
    )
    collector.restart()
    for _ in range(60):  # 60 chunks x 2 steps: several whole episodes per env, then a cut
        collector.step(rl_loop.execute_reference)
    env.close()
    kept = retain_last_episodes(buf, 3)
    ended = kept.column("ended")
    episodes = kept.column("episode")
    assert len(set(episodes.tolist())) == 3
    time_frac = kept.column("state")[:, IDX["time_frac"]]
    for e in set(episodes.tolist()):  # each kept episode is whole: starts at step 0, ends at its last row
        rows = (episodes == e).nonzero().flatten()
        assert float(time_frac[rows[0]]) == 0.0
        assert int(ended[rows].sum()) == 1 and bool(ended[rows[-1]])
    in_flight = set(collector.episode_id.tolist())
    assert not in_flight & set(episodes.tolist())


def test_n_step_returns_follow_the_episode():
    gamma, buf = 0.9, ReplayBuffer(1, 2, 1)
    # one episode of 3 chunks (rewards 1, 2, 4) interleaved with another episode; the last chunk terminates
    for t, r in enumerate([1.0, 2.0, 4.0]):
        buf.add(
            torch.tensor([[float(t)]]),
            torch.zeros(1, 2, 1),
            torch.zeros(1, 2, 1),
            torch.tensor([r]),
            torch.tensor([[float(t + 1)]]),
            torch.zeros(1, 2, 1),
            torch.tensor([t == 2]),
            0,
            0,
        )
        buf.add(
            torch.tensor([[50.0]]),
            torch.zeros(1, 2, 1),
            torch.zeros(1, 2, 1),
            torch.tensor([9.0]),
            torch.tensor([[51.0]]),
            torch.zeros(1, 2, 1),
            torch.tensor([False]),
            0,
            1,
        )
    gh = gamma**2
    batch = buf._n_step(buf.gather(torch.tensor([0, 2, 4])), 2, gamma)
    assert batch.reward.tolist() == pytest.approx([1 + gh * 2, 2 + gh * 4, 4.0])
    assert batch.next_state.flatten().tolist() == [2.0, 3.0, 3.0]
    assert batch.discount.tolist() == pytest.approx([gh * gh, 0.0, 0.0])  # terminal chunks don't bootstrap
    batch = buf._n_step(buf.gather(torch.tensor([5])), 3, gamma)  # episode 1 has no later chunk yet
    assert batch.reward.tolist() == [9.0] and batch.discount.tolist() == pytest.approx([gh])


def test_n_step_chains_rows_of_one_episode_within_and_across_adds_and_never_across_tasks():
    """Kills replay `ReplayBuffer._link_episodes` 4 (episodes linked across tasks), 10 and 12 (the rows of
    one `add` linked to `start - i`)."""
    gamma, buf = 0.9, ReplayBuffer(1, 2, 1)

    def add(rewards, tasks, episodes):
        n = len(rewards)
        z = torch.zeros(n, 2, 1)
        s = torch.zeros(n, 1)
        buf.add(s, z, z, torch.tensor(rewards), s, z, torch.zeros(n, dtype=torch.bool), torch.tensor(tasks), episodes)

    add([1.0, 2.0], [0, 0], 0)  # rows 0, 1: task 0, episode 0
    add([8.0, 4.0], [1, 0], 0)  # row 2: task 1, episode 0; row 3: task 0, episode 0 again
    gh = gamma**2
    batch = buf._n_step(buf.gather(torch.tensor([0, 1, 2])), 3, gamma)
    assert batch.reward.tolist() == pytest.approx([1 + gh * 2 + gh * gh * 4, 2 + gh * 4, 8.0])


def test_add_refuses_a_scalar_where_a_row_per_transition_is_needed_in_one_line():
    """Kills replay `ReplayBuffer.add` 50 (any 0-d column broadcast to N rows), 62 and 63 (the message)."""
    buf, n = ReplayBuffer(D, H, A), 2
    s, chunk = torch.zeros(n, D), torch.zeros(n, H, A)
    with pytest.raises(AccrueError) as exc:
        buf.add(s, chunk, chunk, torch.tensor(1.0), s, chunk, torch.zeros(n, dtype=torch.bool), 0, 0)
    assert str(exc.value) == "replay add: reward has shape (), expected (2,)"
    assert len(buf) == 0
