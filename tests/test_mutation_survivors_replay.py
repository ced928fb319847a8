"""Tests written to kill mutants of accrue/learner/replay.py that survived mutmut's round-1 sweep over the rest
of accrue/learner (docs/MUTATION.md). Each test's docstring names the mutmut ids it kills.

The expected values are written out by hand: exact error messages, the exact bytes of index.json, the rows a
save/load round trip gives back, the capacity a new buffer is built with. The `meta` device stands in for an
accelerator where a test checks that a device argument is honoured (it holds no data, so only empty buffers
and whole-batch moves use it).
"""

from __future__ import annotations

import json
import re

import pytest
import torch

from accrue.errors import AccrueError
from accrue.learner import ReplayBuffer, retain_last_episodes
from accrue.learner.replay import Batch

pytestmark = pytest.mark.usefixtures("one_torch_thread")

D, H, A = 2, 2, 1
SHARD = "shard-0000000000-0000000003.safetensors"


def add_rows(
    buf: ReplayBuffer, n: int, task=0, episode=0, start: float = 0.0, done=None, ended=None, intervention=None
):
    """n rows whose every column differs from row to row (and from the other columns)."""
    s = torch.arange(n * D, dtype=torch.float32).view(n, D) + start
    chunk = torch.arange(n * H * A, dtype=torch.float32).view(n, H, A) + start
    done = torch.zeros(n, dtype=torch.bool) if done is None else torch.as_tensor(done)
    reward = torch.arange(n, dtype=torch.float32) + start
    buf.add(
        s, chunk, -chunk, reward, s + 0.5, chunk + 0.25, done, task, episode, ended=ended, intervention=intervention
    )


def raises_exactly(message: str):
    return pytest.raises(AccrueError, match="^" + re.escape(message) + "$")


def saved(tmp_path, n: int = 3) -> tuple[ReplayBuffer, object]:
    buf = ReplayBuffer(D, H, A)
    add_rows(buf, n, episode=torch.arange(n))
    directory = tmp_path / "r"
    buf.save_new_shards(directory)
    return buf, directory


def edit_index(directory, **changes) -> None:
    index = json.loads((directory / "index.json").read_text())
    index.update(changes)
    (directory / "index.json").write_text(json.dumps(index))


# ------------------------------------------------------------------------------------------- Batch
def test_with_teacher_without_row_index_names_the_way_out():
    """Kills replay `Batch.with_teacher` 2, 3, 4, 5 (the exact message)."""
    batch = Batch(*(torch.zeros(1, 1) for _ in range(7)))
    with raises_exactly("batch has no row index; sample it from a ReplayBuffer to attach teacher targets"):
        batch.with_teacher(torch.zeros(1, 1))


def test_to_device_moves_every_set_field_and_keeps_unset_ones_none():
    """Kills replay `Batch.to_device` 1, 3-15: the same device gives the batch itself; another device (meta,
    standing in for an accelerator) gets a new batch with every tensor moved and every None field still None."""
    buf = ReplayBuffer(D, H, A)
    add_rows(buf, 3)
    batch = buf.gather(torch.tensor([2, 0]))
    assert batch.to_device("cpu") is batch
    moved = batch.to_device("meta")
    assert moved is not batch and batch.state.device == torch.device("cpu")
    for name in ("state", "action", "ref", "reward", "next_state", "next_ref", "done", "task", "episode", "index"):
        got, was = getattr(moved, name), getattr(batch, name)
        assert got.device == torch.device("meta") and got.shape == was.shape and got.dtype == was.dtype, name
    for name in ("ended", "intervention"):
        assert getattr(moved, name).device == torch.device("meta"), name
    assert moved.discount is None and moved.teacher is None and moved.fresh_ref is None


# ------------------------------------------------------------------------------------------- reading
def test_gather_returns_every_column_of_the_rows():
    """Kills replay `ReplayBuffer.gather` 11, 12, 14, 15, 23, 24, 26, 27 (task, episode, ended, intervention)."""
    buf = ReplayBuffer(D, H, A)
    add_rows(
        buf,
        4,
        task=torch.tensor([3, 4, 5, 6]),
        episode=torch.tensor([7, 8, 9, 10]),
        ended=torch.tensor([False, True, False, True]),
        intervention=torch.tensor([True, False, False, True]),
    )
    batch = buf.gather(torch.tensor([3, 0, 1]))
    assert batch.task.tolist() == [6, 3, 4]
    assert batch.episode.tolist() == [10, 7, 8]
    assert batch.ended.tolist() == [True, False, True]
    assert batch.intervention.tolist() == [True, True, False]
    assert batch.index.tolist() == [3, 0, 1]


def test_sample_errors_are_exact():
    """Kills replay `ReplayBuffer.sample` 5 and 25, 26, 27 (the exact messages)."""
    with raises_exactly("replay buffer is empty: collect warmup episodes before updating"):
        ReplayBuffer(D, H, A).sample(1, torch.Generator())
    buf = ReplayBuffer(D, H, A)
    add_rows(buf, 2)
    with raises_exactly("n-step sampling needs gamma"):
        buf.sample(1, torch.Generator(), n_step=2)


def test_sample_draws_its_rows_on_the_generators_device_not_torchs_default():
    """Kills replay `ReplayBuffer.sample` 13, 18 (the indices drawn on torch's default device). A program may
    set another default device (an accelerator); the rows must still be drawn where the caller's generator
    is. With the default set to `meta`, an index drawn there cannot be moved to the CPU buffer."""
    buf = ReplayBuffer(D, H, A)
    add_rows(buf, 6)
    want = buf.sample(5, torch.Generator().manual_seed(3))
    with torch.device("meta"):
        got = buf.sample(5, torch.Generator(device="cpu").manual_seed(3))
    assert got.index.device == torch.device("cpu")
    assert got.index.tolist() == want.index.tolist()
    assert torch.equal(got.state, want.state)


@pytest.fixture(scope="module")
def meta_indexing():
    """The first index into a meta tensor in a process imports torch's symbolic shapes (sympy, ~2 s on a busy
    machine): paid once here, not inside a test's timing."""
    torch.zeros(2, device="meta")[torch.tensor([1])]


@pytest.mark.usefixtures("meta_indexing")
def test_a_buffer_gathers_rows_given_on_another_device_onto_its_own(tmp_path):
    """Kills replay `ReplayBuffer.gather` 2 (the row index left where the caller made it). A batch lives on
    one device (`Batch.to_device` looks only at its state): a buffer on an accelerator (meta stands in for
    one, loaded from a saved replay) given CPU rows returns a batch whose every tensor, the row index
    included, is on the buffer's device."""
    _, directory = saved(tmp_path)
    buf = ReplayBuffer.load(directory, device="meta")
    for batch in (buf.gather(torch.tensor([2, 0])), buf.sample(2, torch.Generator().manual_seed(0))):
        for name in ("state", "action", "ref", "reward", "next_state", "next_ref", "done", "task", "episode"):
            assert getattr(batch, name).device == torch.device("meta"), name
        for name in ("index", "ended", "intervention"):
            assert getattr(batch, name).device == torch.device("meta"), name
        assert batch.index.shape == (2,)


def n_step_buffer() -> ReplayBuffer:
    """Episode 0: 3 chunks (rewards 1, 2, 4), the last one terminates; distinct next_state and next_ref."""
    buf = ReplayBuffer(1, 1, 1)
    for t, r in enumerate([1.0, 2.0, 4.0]):
        buf.add(
            torch.tensor([[float(t)]]),
            torch.zeros(1, 1, 1),
            torch.zeros(1, 1, 1),
            torch.tensor([r]),
            torch.tensor([[10.0 + t]]),
            torch.full((1, 1, 1), 20.0 + t),
            torch.tensor([t == 2]),
            0,
            0,
        )
    return buf


def test_two_step_sampling_sums_the_next_chunk_and_takes_its_done_and_next_inputs():
    """Kills replay `ReplayBuffer.sample` 23 (n_step=2 is n-step) and `ReplayBuffer._n_step` 64, 70, 73 (the
    batch takes the last reached chunk's done and next_ref)."""
    gamma = 0.5  # horizon 1: γ^H = 0.5
    buf = n_step_buffer()
    gen = torch.Generator().manual_seed(0)
    want_idx = torch.randint(0, 3, (64,), generator=torch.Generator().manual_seed(0))
    batch = buf.sample(64, gen, n_step=2, gamma=gamma)
    assert batch.index.tolist() == want_idx.tolist() and set(want_idx.tolist()) == {0, 1, 2}
    by_row = {
        0: (1 + 0.5 * 2, 0.0, 0.25, 11.0, 21.0),  # reward, done, discount, next_state, next_ref of chunk 1
        1: (2 + 0.5 * 4, 1.0, 0.0, 12.0, 22.0),  # chunk 2 terminates: done, no bootstrap
        2: (4.0, 1.0, 0.0, 12.0, 22.0),  # already terminal: itself
    }
    for i, row in enumerate(want_idx.tolist()):
        reward, done, discount, next_state, next_ref = by_row[row]
        assert float(batch.reward[i]) == reward
        assert float(batch.done[i]) == done
        assert float(batch.discount[i]) == discount
        assert float(batch.next_state[i, 0]) == next_state
        assert float(batch.next_ref[i, 0, 0]) == next_ref


# ------------------------------------------------------------------------------------------- saving
def test_save_creates_nested_directories_and_writes_the_exact_index(tmp_path):
    """Kills replay `ReplayBuffer.save_new_shards` 3, 5, 7 (parents created), 36, 37 (the `format` key),
    66, 67, 69, 70, 71, 72 (the exact bytes of index.json: indent 1, sorted keys; a content-addressed
    store dedupes it only if it is byte-identical)."""
    buf = ReplayBuffer(D, H, A)
    add_rows(buf, 3)
    directory = tmp_path / "a" / "b" / "c"
    assert [p.name for p in buf.save_new_shards(directory)] == [SHARD]
    add_rows(buf, 2, start=100.0)
    buf.save_new_shards(directory)
    text = (directory / "index.json").read_text()
    assert text == (
        "{\n"
        ' "action_dim": 1,\n'
        ' "format": 1,\n'
        ' "horizon": 2,\n'
        ' "shards": [\n'
        "  {\n"
        '   "count": 3,\n'
        '   "file": "shard-0000000000-0000000003.safetensors",\n'
        '   "start": 0\n'
        "  },\n"
        "  {\n"
        '   "count": 2,\n'
        '   "file": "shard-0000000003-0000000002.safetensors",\n'
        '   "start": 3\n'
        "  }\n"
        " ],\n"
        ' "size": 5,\n'
        ' "state_dim": 2\n'
        "}\n"
    )
    assert sorted(p.name for p in directory.iterdir()) == [
        "index.json",
        "shard-0000000000-0000000003.safetensors",
        "shard-0000000003-0000000002.safetensors",
    ]


def test_interventions_round_trip_through_a_shard(tmp_path):
    """Kills replay `ReplayBuffer._write_shard` 12 (a shard holds the intervention column where a row is set)."""
    buf = ReplayBuffer(D, H, A)
    add_rows(buf, 3, intervention=torch.tensor([False, True, False]))
    buf.save_new_shards(tmp_path / "r")
    from safetensors import safe_open

    with safe_open(str(tmp_path / "r" / SHARD), "pt") as f:
        assert "intervention" in set(f.keys())
    assert ReplayBuffer.load(tmp_path / "r").column("intervention").tolist() == [False, True, False]


# ------------------------------------------------------------------------------------------- loading
def test_load_sizes_the_buffer_to_its_rows_and_honours_the_device(tmp_path):
    """Kills replay `ReplayBuffer.load` 18, 32 (capacity = the index's size, at least 1) and 17 (the buffer is
    built on the device asked for; meta stands in for an accelerator)."""
    _, one = saved(tmp_path, 1)
    assert ReplayBuffer.load(one).capacity == 1
    empty = tmp_path / "empty"
    ReplayBuffer(D, H, A).save_new_shards(empty)
    assert ReplayBuffer.load(empty).capacity == 1
    assert ReplayBuffer.load(empty, device="meta").device == torch.device("meta")
    buf = ReplayBuffer(D, H, A)
    add_rows(buf, 5)
    buf.save_new_shards(tmp_path / "five")
    assert ReplayBuffer.load(tmp_path / "five").capacity == 5


def test_load_of_a_malformed_index_is_one_exact_error(tmp_path):
    """Kills replay `ReplayBuffer.load` 40, 41 (the message names the index file and the cause)."""
    _, directory = saved(tmp_path)
    (directory / "index.json").write_text("{}")
    with raises_exactly(f"{directory / 'index.json'}: malformed replay index ('state_dim')"):
        ReplayBuffer.load(directory)


def test_a_shard_written_before_episodes_were_marked_loads_ended_as_done(tmp_path):
    """Kills replay `ReplayBuffer.load` 52, 54 (an old shard without `ended`: ended = done)."""
    from safetensors.torch import load_file, save_file

    buf = ReplayBuffer(D, H, A)
    add_rows(buf, 3, done=torch.tensor([False, True, False]), ended=torch.tensor([True, True, True]))
    buf.save_new_shards(tmp_path / "r")
    path = tmp_path / "r" / SHARD
    rows = load_file(str(path))
    del rows["ended"]
    save_file(rows, str(path))
    loaded = ReplayBuffer.load(tmp_path / "r")
    assert loaded.column("ended").tolist() == [False, True, False]
    assert loaded.column("done").tolist() == [False, True, False]


def test_a_shard_with_the_wrong_row_count_is_refused(tmp_path):
    """Kills replay `ReplayBuffer.load` 68, 78: the index says 2 rows (start and size agree with it), the shard
    holds 3."""
    _, directory = saved(tmp_path)
    index = json.loads((directory / "index.json").read_text())
    index["shards"][0]["count"] = 2
    edit_index(directory, shards=index["shards"], size=3)
    with raises_exactly(f"{directory / SHARD}: replay shard does not match the index"):
        ReplayBuffer.load(directory)


def test_an_index_size_that_disagrees_with_its_shards_is_refused(tmp_path):
    """Kills replay `ReplayBuffer.load` 90, 91, 92, 93 (the exact message with both sizes)."""
    _, directory = saved(tmp_path)
    edit_index(directory, size=4)
    with raises_exactly(f"{directory / 'index.json'}: index size 4 != rows in shards 3"):
        ReplayBuffer.load(directory)


# ------------------------------------------------------------------------------------------- new buffers
def test_select_and_concat_size_the_new_buffer_exactly():
    """Kills replay `ReplayBuffer.select` 11, 16 and `ReplayBuffer.concat` 13, 18 (capacity = the rows, at
    least 1), `select` 10 and `concat` 12 (the new buffer is on the source's device; meta, empty)."""
    buf = ReplayBuffer(D, H, A)
    add_rows(buf, 3)
    assert buf.select(torch.tensor([1])).capacity == 1
    assert buf.select(torch.tensor([2, 0, 1])).capacity == 3
    assert buf.select(torch.tensor([], dtype=torch.long)).capacity == 1
    one = buf.select(torch.tensor([2]))
    assert ReplayBuffer.concat([one]).capacity == 1
    assert ReplayBuffer.concat([buf, one]).capacity == 4
    assert ReplayBuffer.concat([ReplayBuffer(D, H, A)]).capacity == 1
    meta = ReplayBuffer(D, H, A, device="meta")
    assert meta.select(torch.tensor([], dtype=torch.long)).device == torch.device("meta")
    assert ReplayBuffer.concat([meta]).device == torch.device("meta")


def test_concat_of_different_shapes_is_one_exact_error():
    """Kills replay `ReplayBuffer.concat` 21, 22, 23."""
    with raises_exactly("replay concat: buffers have different state/chunk shapes"):
        ReplayBuffer.concat([ReplayBuffer(D, H, A), ReplayBuffer(D, H + 1, A)])


# ------------------------------------------------------------------------------------------- retention
def test_retain_one_episode_and_a_negative_n():
    """Kills replay `retain_last_episodes` 10 (n = 1 keeps the last ended episode) and 3 (the exact message)."""
    buf = ReplayBuffer(D, H, A)
    add_rows(buf, 2, episode=0, ended=torch.tensor([False, True]))
    add_rows(buf, 2, episode=1, start=10.0, ended=torch.tensor([False, True]))
    kept = retain_last_episodes(buf, 1)
    assert kept.column("episode").tolist() == [1, 1]
    assert torch.equal(kept.column("state"), buf.column("state")[2:])
    with raises_exactly("retain_last_episodes: n must be >= 0 (got -1)"):
        retain_last_episodes(buf, -1)


# ------------------------------------------------------------------------------------------- construction, growth
def test_a_new_buffer_holds_six_dim_actions_and_1024_rows_by_default():
    """Kills replay `ReplayBuffer.__init__` 1 (action_dim defaults to 6: `replay_from_episodes` builds its
    buffers without one, for the arm's 6 joints) and 4 (1024 rows before the first growth)."""
    buf = ReplayBuffer(D, H)
    assert buf.action_dim == 6 and buf.capacity == 1024
    chunk = torch.ones(1, H, 6)
    buf.add(torch.ones(1, D), chunk, chunk, torch.ones(1), torch.ones(1, D), chunk, torch.tensor([False]), 0, 0)
    assert buf.column("action").shape == (1, H, 6)


def test_a_buffer_built_under_another_default_device_keeps_its_storage_on_its_own():
    """Kills replay `ReplayBuffer.__init__` 21, 24 (the columns) and 29, 33 (the next-chunk pointers) made on
    torch's default device. A program may set another default device (an accelerator; meta stands in for
    one) and still build a CPU buffer: rows added later, after the default is back, must be readable, and
    n-step sampling must follow the pointers."""
    with torch.device("meta"):
        buf = ReplayBuffer(D, H, A, device="cpu")
    add_rows(buf, 2)
    for name in ("state", "action", "ref", "reward", "next_state", "next_ref", "done", "task", "episode"):
        assert buf.column(name).device == torch.device("cpu"), name
    assert buf.column("reward").tolist() == [0.0, 1.0]
    batch = buf.sample(8, torch.Generator().manual_seed(0), n_step=2, gamma=0.5)
    rewards = {0: 0.0 + 0.25 * 1.0, 1: 1.0}  # γ^H = 0.25; row 0's next chunk is row 1
    assert batch.reward.tolist() == [rewards[i] for i in batch.index.tolist()]


def test_growing_doubles_the_capacity_and_keeps_every_row_and_pointer():
    """Kills replay `ReplayBuffer._grow` 5 (the capacity doubles: 1 → 4 → 8) and 26 (rows made by a growth
    have no next chunk until one is added: an episode's last row, added after a growth, ends its n-step sum).
    Every column keeps its values and dtype across the growths."""
    buf = ReplayBuffer(D, H, A, initial_capacity=1)
    flat = ReplayBuffer(D, H, A)  # the same rows, never grown
    caps = [buf.capacity]
    for b in (buf, flat):
        add_rows(b, 1, episode=0)
    caps.append(buf.capacity)
    for b in (buf, flat):
        add_rows(b, 2, episode=torch.tensor([1, 0]), start=10.0, intervention=torch.tensor([True, False]))
    caps.append(buf.capacity)
    for b in (buf, flat):
        add_rows(b, 2, task=3, episode=2, start=20.0, ended=torch.tensor([False, True]))
    caps.append(buf.capacity)
    assert caps == [1, 1, 4, 8] and len(buf) == 5
    dtypes = {"done": torch.bool, "task": torch.int64, "episode": torch.int64, "ended": torch.bool}
    dtypes["intervention"] = torch.bool
    for name in ("state", "action", "ref", "reward", "next_state", "next_ref", *dtypes):
        got = buf.column(name)
        assert got.dtype == dtypes.get(name, torch.float32) and got.device == torch.device("cpu"), name
        assert torch.equal(got, flat.column(name)), name
    assert buf.column("reward").tolist() == [0.0, 10.0, 11.0, 20.0, 21.0]
    assert buf.column("intervention").tolist() == [False, True, False, False, False]
    # episodes: 0 = rows 0, 2; 1 = row 1; 2 = rows 3, 4. Two-step sums with γ^H = 0.25:
    want = {0: 0.0 + 0.25 * 11.0, 1: 10.0, 2: 11.0, 3: 20.0 + 0.25 * 21.0, 4: 21.0}
    batch = buf.sample(64, torch.Generator().manual_seed(0), n_step=2, gamma=0.5)
    assert set(batch.index.tolist()) == set(want)
    assert batch.reward.tolist() == [want[i] for i in batch.index.tolist()]
