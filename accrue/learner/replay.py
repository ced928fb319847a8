"""Replay of chunk transitions (s, a, ã, R^(H), s_{t+H}, ã_{t+H}, done, task, episode, ended, intervention)
and the retention rule.

- Storage is a set of growable tensors on one device (CPU or GPU); `sample` draws uniform indices from a
  caller-owned torch.Generator, so sampling is deterministic and resumable.
- `done` must be the *termination* flag (success); a time-limit truncation still bootstraps from s_{t+H}.
- `ended` marks the transition in which an episode reached its end (success or time limit). An episode
  without one is a fragment: cut by the stage's budget or by the restart after an intra-step checkpoint.
- Persistence is append-only: `save_new_shards(dir)` writes only the rows added since the last save as a
  new safetensors shard plus a small JSON index; earlier shards are rewritten byte-identically when the
  target directory lacks them, so a content-addressed store dedupes them. No capacity eviction: a stage
  has a fixed env-step budget, so the buffer is bounded by it (and eviction would break the shards).
- `intervention` (beyond the paper, docs/DEPARTURES.md item 12) marks a transition whose chunk the operator
  drove, in part or whole, through a teleoperator on the robot (lerobot HIL-SERL's `is_intervention`). It is
  stored and counted, never read by a loss. A shard holds it only where one of its rows is set, so a replay
  without interventions (every simulator replay) writes exactly the shards it wrote before the column
  existed; a shard without it loads as all False.
- `retain_last_episodes(buffer, n)` is the paper's memory B^{<k}: the last N complete episodes of each task.
"""

from __future__ import annotations

import dataclasses
import json
import os
from dataclasses import dataclass
from pathlib import Path

import torch

from accrue.errors import AccrueError

INDEX_FILE = "index.json"
FORMAT_VERSION = 1
_FIELDS = ("state", "action", "ref", "reward", "next_state", "next_ref", "done", "task", "episode", "ended")
SPARSE_FIELDS = ("intervention",)  # in a shard only where one of its rows is set (absent: all False)
_COLUMNS = _FIELDS + SPARSE_FIELDS


@dataclass
class Batch:
    state: torch.Tensor  # (B, D)
    action: torch.Tensor  # (B, H, d)
    ref: torch.Tensor  # (B, H, d)  ã_t
    reward: torch.Tensor  # (B,)       R^(H) (or the n-step sum of chunk returns)
    next_state: torch.Tensor  # (B, D)     s_{t+H}
    next_ref: torch.Tensor  # (B, H, d)  ã_{t+H}
    done: torch.Tensor  # (B,) float, 1 = terminated (no bootstrap)
    task: torch.Tensor | None = None
    episode: torch.Tensor | None = None
    index: torch.Tensor | None = None  # rows of the buffer the batch came from
    discount: torch.Tensor | None = None  # bootstrap discount; None → γ^H · (1 − done)
    teacher: torch.Tensor | None = None  # Eq. 3 cached targets â_j (prior memory only)
    fresh_ref: torch.Tensor | None = None  # current base policy's chunk at s_j (distill_inputs fresh/both)
    ended: torch.Tensor | None = None  # (B,) bool, the episode ended in this transition
    intervention: torch.Tensor | None = None  # (B,) bool, the operator drove (part of) this chunk

    def __len__(self) -> int:
        return self.state.shape[0]

    def with_teacher(self, targets: torch.Tensor, fresh_ref: torch.Tensor | None = None) -> "Batch":
        """Attach the cached Eq. 3 targets (and fresh reference chunks) of the sampled rows; both are indexed
        like the buffer."""
        if self.index is None:
            raise AccrueError("batch has no row index; sample it from a ReplayBuffer to attach teacher targets")

        def rows(t):
            return None if t is None else t[self.index.to(t.device)].to(self.state.device)

        return dataclasses.replace(self, teacher=rows(targets), fresh_ref=rows(fresh_ref))

    def to_device(self, device: torch.device) -> "Batch":
        if self.state.device == torch.device(device):
            return self
        return Batch(
            **{
                f.name: (None if getattr(self, f.name) is None else getattr(self, f.name).to(device))
                for f in dataclasses.fields(Batch)
            }
        )

    @staticmethod
    def cat(a: "Batch", b: "Batch") -> "Batch":
        """Stack two batches (ER and the critic-all-replay ablation use B^k ∪ B^{<k})."""

        def join(x, y):
            return None if x is None or y is None else torch.cat([x, y], 0)

        out = {f.name: join(getattr(a, f.name), getattr(b, f.name)) for f in dataclasses.fields(Batch)}
        out["index"], out["teacher"], out["fresh_ref"] = None, None, None
        return Batch(**out)


class ReplayBuffer:
    def __init__(
        self,
        state_dim: int,
        horizon: int,
        action_dim: int = 6,
        device: str | torch.device = "cpu",
        initial_capacity: int = 1024,
    ):
        self.state_dim, self.horizon, self.action_dim = state_dim, horizon, action_dim
        # what s and a are made of, where a robot made them: {"action_keys": [...], "cameras": [...]} (the
        # index records it; empty for the simulator's buffers, whose index stays as it was)
        self.layout: dict = {}
        self.device = torch.device(device)
        self.size = 0
        self._shards: list[tuple[int, int]] = []  # (start, count) of each shard already written
        self._last_row: dict[tuple[int, int], int] = {}  # (task, episode) → its latest row (for n-step)
        cap = max(1, initial_capacity)
        self._data = {
            name: torch.zeros((cap, *shape), dtype=dtype, device=self.device)
            for name, (shape, dtype) in self._layout().items()
        }
        self._next_row = torch.full((cap,), -1, dtype=torch.long, device=self.device)

    def _layout(self) -> dict[str, tuple[tuple[int, ...], torch.dtype]]:
        chunk = (self.horizon, self.action_dim)
        return {
            "state": ((self.state_dim,), torch.float32),
            "action": (chunk, torch.float32),
            "ref": (chunk, torch.float32),
            "reward": ((), torch.float32),
            "next_state": ((self.state_dim,), torch.float32),
            "next_ref": (chunk, torch.float32),
            "done": ((), torch.bool),
            "task": ((), torch.int64),
            "episode": ((), torch.int64),
            "ended": ((), torch.bool),
            "intervention": ((), torch.bool),
        }

    def __len__(self) -> int:
        return self.size

    @property
    def capacity(self) -> int:
        return self._next_row.shape[0]

    def _grow(self, needed: int) -> None:
        cap = self.capacity
        while cap < needed:
            cap *= 2
        if cap == self.capacity:
            return
        for name, t in self._data.items():
            bigger = torch.zeros((cap, *t.shape[1:]), dtype=t.dtype, device=self.device)
            bigger[: self.size] = t[: self.size]
            self._data[name] = bigger
        nxt = torch.full((cap,), -1, dtype=torch.long, device=self.device)
        nxt[: self.size] = self._next_row[: self.size]
        self._next_row = nxt

    # ---- writing --------------------------------------------------------------------------
    def add(
        self, state, action, ref, reward, next_state, next_ref, done, task, episode, ended=None, intervention=None
    ) -> None:
        """Append N transitions (leading dim N on every array; task/episode may be scalars). `ended` defaults
        to `done` (a caller that never truncates); pass terminated | truncated. `intervention` defaults to
        False on every row (no operator takeover)."""
        state = torch.as_tensor(state, dtype=torch.float32)
        n = state.shape[0]
        cols = {
            "state": state,
            "action": action,
            "ref": ref,
            "reward": reward,
            "next_state": next_state,
            "next_ref": next_ref,
            "done": done,
            "task": task,
            "episode": episode,
            "ended": done if ended is None else ended,
            "intervention": torch.zeros(n, dtype=torch.bool) if intervention is None else intervention,
        }
        layout = self._layout()
        rows = {}
        for name, value in cols.items():
            shape, dtype = layout[name]
            t = torch.as_tensor(value).to(device=self.device, dtype=dtype)
            if t.dim() == 0 and name in ("task", "episode"):
                t = t.expand(n)
            if tuple(t.shape) != (n, *shape):
                raise AccrueError(f"replay add: {name} has shape {tuple(t.shape)}, expected {(n, *shape)}")
            rows[name] = t
        self._write(rows)

    def _write(self, rows: dict[str, torch.Tensor]) -> None:
        n = rows["state"].shape[0]
        self._grow(self.size + n)
        start = self.size
        for name, t in rows.items():
            self._data[name][start : start + n] = t
        self.size += n
        self._link_episodes(start, rows["task"].tolist(), rows["episode"].tolist())

    def _link_episodes(self, start: int, tasks: list[int], episodes: list[int]) -> None:
        # next-chunk pointers, derived from append order within an episode (never stored in shards)
        for i, key in enumerate(zip(tasks, episodes)):
            prev = self._last_row.get(key)
            if prev is not None:
                self._next_row[prev] = start + i
            self._last_row[key] = start + i

    # ---- reading --------------------------------------------------------------------------
    def column(self, name: str) -> torch.Tensor:
        return self._data[name][: self.size]

    def gather(self, idx: torch.Tensor) -> Batch:
        idx = idx.to(self.device)
        d = self._data
        return Batch(
            state=d["state"][idx],
            action=d["action"][idx],
            ref=d["ref"][idx],
            reward=d["reward"][idx],
            next_state=d["next_state"][idx],
            next_ref=d["next_ref"][idx],
            done=d["done"][idx].float(),
            task=d["task"][idx],
            episode=d["episode"][idx],
            index=idx,
            ended=d["ended"][idx],
            intervention=d["intervention"][idx],
        )

    def sample(self, n: int, generator: torch.Generator, n_step: int = 1, gamma: float | None = None) -> Batch:
        """n uniform rows. With n_step > 1 (needs gamma) the return sums the next chunks of the same episode:
        R = Σ_m γ^{mH} R_{t+mH}, bootstrapping from the last reached chunk with discount γ^{(m+1)H}."""
        if self.size == 0:
            raise AccrueError("replay buffer is empty: collect warmup episodes before updating")
        idx = torch.randint(0, self.size, (n,), generator=generator, device=generator.device).to(self.device)
        batch = self.gather(idx)
        if n_step > 1:
            if gamma is None:
                raise AccrueError("n-step sampling needs gamma")
            batch = self._n_step(batch, n_step, gamma)
        return batch

    def _n_step(self, batch: Batch, n_step: int, gamma: float) -> Batch:
        g_h = gamma**self.horizon
        reward, done = batch.reward.clone(), batch.done.clone()
        last, scale = batch.index.clone(), torch.ones_like(reward)
        for _ in range(n_step - 1):
            nxt = self._next_row[last]
            go = (done == 0) & (nxt >= 0)  # continue only inside an unfinished, recorded episode
            if not bool(go.any()):
                break
            safe = torch.where(go, nxt, last)
            scale = torch.where(go, scale * g_h, scale)
            reward = reward + torch.where(go, scale * self._data["reward"][safe], torch.zeros_like(reward))
            done = torch.where(go, self._data["done"][safe].float(), done)
            last = safe
        d = self._data
        discount = scale * g_h * (1.0 - done)
        return dataclasses.replace(
            batch,
            reward=reward,
            done=done,
            discount=discount,
            next_state=d["next_state"][last],
            next_ref=d["next_ref"][last],
        )

    # ---- persistence (append-only shards + JSON index) -----------------------------------
    def _shard_name(self, start: int, count: int) -> str:
        return f"shard-{start:010d}-{count:010d}.safetensors"

    def _write_shard(self, directory: Path, start: int, count: int) -> Path:
        from safetensors.torch import save_file

        path = directory / self._shard_name(start, count)
        rows = {name: self._data[name][start : start + count] for name in _COLUMNS}
        names = _FIELDS + tuple(name for name in SPARSE_FIELDS if bool(rows[name].any()))
        tensors = {name: rows[name].detach().to("cpu").contiguous() for name in names}
        tmp = path.with_suffix(".tmp")
        save_file(tensors, str(tmp))
        os.replace(tmp, path)
        return path

    def save_new_shards(self, directory: str | Path) -> list[Path]:
        """Write the rows added since the last save as one new shard and update the index.

        Shards already recorded but missing from `directory` are rewritten (byte-identical, same bounds).
        Returns the shard files written by this call.
        """
        directory = Path(directory)
        directory.mkdir(parents=True, exist_ok=True)
        written = [
            self._write_shard(directory, s, c)
            for s, c in self._shards
            if not (directory / self._shard_name(s, c)).exists()
        ]
        saved = sum(c for _, c in self._shards)
        if self.size > saved:
            self._shards.append((saved, self.size - saved))
            written.append(self._write_shard(directory, saved, self.size - saved))
        index = {
            "format": FORMAT_VERSION,
            "state_dim": self.state_dim,
            "horizon": self.horizon,
            "action_dim": self.action_dim,
            "size": self.size,
            "shards": [{"file": self._shard_name(s, c), "start": s, "count": c} for s, c in self._shards],
        }
        if self.layout:
            index["layout"] = self.layout
        tmp = directory / (INDEX_FILE + ".tmp")
        tmp.write_text(json.dumps(index, indent=1, sort_keys=True) + "\n")
        os.replace(tmp, directory / INDEX_FILE)
        return written

    save_shards = save_new_shards

    @classmethod
    def load(cls, directory: str | Path, device: str | torch.device = "cpu") -> "ReplayBuffer":
        from safetensors import SafetensorError
        from safetensors.torch import load_file

        directory = Path(directory)
        try:
            index = json.loads((directory / INDEX_FILE).read_text())
            buf = cls(
                int(index["state_dim"]),
                int(index["horizon"]),
                int(index["action_dim"]),
                device=device,
                initial_capacity=max(1, int(index["size"])),
            )
            shards = index["shards"]
            buf.layout = dict(index.get("layout") or {})
        except FileNotFoundError:
            raise AccrueError(f"{directory}: not a replay buffer (no {INDEX_FILE})") from None
        except (ValueError, KeyError, TypeError) as exc:
            raise AccrueError(f"{directory / INDEX_FILE}: malformed replay index ({exc})") from None
        try:  # every shard entry is read before any shard, so a bad entry is the index's error
            entries = [(directory / str(s["file"]), int(s["start"]), int(s["count"])) for s in shards]
        except (ValueError, KeyError, TypeError) as exc:
            raise AccrueError(f"{directory / INDEX_FILE}: malformed replay index (shard entry: {exc})") from None
        for path, start, count in entries:
            if not path.exists():
                raise AccrueError(f"{path}: replay shard listed in the index is missing")
            try:
                rows = load_file(str(path))
                rows.setdefault("ended", rows["done"].clone())  # shards written before episodes were marked
                rows.setdefault("intervention", torch.zeros_like(rows["done"]))  # no row of it was taken over
                rows_in_shard = rows["state"].shape[0]
            except (SafetensorError, KeyError) as exc:
                raise AccrueError(f"{path}: corrupt replay shard ({exc})") from None
            if rows_in_shard != count or start != buf.size:
                raise AccrueError(f"{path}: replay shard does not match the index")
            buf._write(rows)
            buf._shards.append((start, count))
        if buf.size != index["size"]:
            raise AccrueError(f"{directory / INDEX_FILE}: index size {index['size']} != rows in shards {buf.size}")
        return buf

    # ---- building new buffers --------------------------------------------------------------
    def select(self, rows: torch.Tensor) -> "ReplayBuffer":
        """A new buffer holding the given rows (in the given order), with no shard history."""
        out = ReplayBuffer(
            self.state_dim, self.horizon, self.action_dim, self.device, initial_capacity=max(1, rows.numel())
        )
        out.layout = dict(self.layout)
        if rows.numel():
            out._write({name: self._data[name][rows.to(self.device)] for name in _COLUMNS})
        return out

    @staticmethod
    def concat(buffers: list["ReplayBuffer"]) -> "ReplayBuffer":
        first = buffers[0]
        out = ReplayBuffer(
            first.state_dim,
            first.horizon,
            first.action_dim,
            first.device,
            initial_capacity=max(1, sum(len(b) for b in buffers)),
        )
        layouts = [b.layout for b in buffers if b.layout]
        if any(lay != layouts[0] for lay in layouts):
            raise AccrueError(
                f"replay concat: buffers come from different robot inputs ({layouts[0]} and "
                f"{next(lay for lay in layouts if lay != layouts[0])})"
            )
        out.layout = dict(layouts[0]) if layouts else {}
        for b in buffers:
            if (b.state_dim, b.horizon, b.action_dim) != (first.state_dim, first.horizon, first.action_dim):
                raise AccrueError("replay concat: buffers have different state/chunk shapes")
            if len(b):
                out._write({name: b.column(name).to(out.device) for name in _COLUMNS})
        return out


def complete_episodes(buffer: ReplayBuffer) -> dict[int, list[int]]:
    """task -> the episodes that ended inside the buffer (success or time limit), ordered by when they ended."""
    task, episode, ended = (buffer.column(c).tolist() for c in ("task", "episode", "ended"))
    out: dict[int, list[int]] = {}
    for t, e, end in zip(task, episode, ended):
        if end:
            out.setdefault(t, []).append(e)
    return out


def retain_last_episodes(buffer: ReplayBuffer, n: int) -> ReplayBuffer:
    """The paper's retained memory: for each task in `buffer`, its last n episodes that ended (success or
    time limit), whole, all their transitions in original order. Fragments — episodes cut by the budget's
    end or by an intra-step checkpoint's restart — never count. A task with fewer than n complete episodes
    keeps what it has (`complete_episodes` tells how many). Pool finished tasks with
    `retain_last_episodes(ReplayBuffer.concat([prior, current]), n)` — prior tasks already hold ≤ n."""
    if n < 0:
        raise AccrueError(f"retain_last_episodes: n must be >= 0 (got {n})")
    keep = {(t, e) for t, eps in complete_episodes(buffer).items() for e in (eps[-n:] if n > 0 else [])}
    task, episode = buffer.column("task").tolist(), buffer.column("episode").tolist()
    rows = torch.tensor([r for r, key in enumerate(zip(task, episode)) if key in keep], dtype=torch.long)
    return buffer.select(rows)
