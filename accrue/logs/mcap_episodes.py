"""Episode logs as MCAP: one sealed file per episode, readable in Foxglove and with the `mcap` reader.

Crash safety: an episode is written to a hidden temporary name (`.episode-000007.mcap.partial`)
and only renamed to its final name (`episode-000007.mcap`) after the MCAP summary and footer are
written and the bytes are fsynced. A crash therefore loses at most the episodes in progress, and
a file under a final name is always complete. Leftover `.partial` files can be inspected with
`mcap.reader.NonSeekingReader`, but nothing in accrue reads them.

Topics and schemas (messages are JSON; schemas are JSON Schema, named as below):

| topic            | schema                    | when                                             |
|------------------|---------------------------|--------------------------------------------------|
| /state           | accrue.State              | steps where a state is given (names in channel   |
|                  |                           | metadata; inside an action chunk only the first  |
|                  |                           | step has an observed state)                      |
| /action          | accrue.Action             | every step                                       |
| /reward          | accrue.Reward             | every step (reward and the return so far)        |
| /reference       | accrue.ReferenceChunk     | steps where a reference chunk is given           |
| /ee/pose         | foxglove.PoseInFrame      | steps where an end-effector pose is given        |
| /socket/pose     | foxglove.PoseInFrame      | steps where a socket pose is given               |
| /wrist/wrench    | accrue.Wrench             | steps where a wrist force/torque is given        |
| /camera/<name>   | foxglove.CompressedImage  | steps where an image is given (jpeg or png);     |
|                  |                           | <name> is the recorder's camera, default wrist   |
| /episode/label   | accrue.EpisodeLabel       | once, at the end                                 |

Joint states are not logged: accrue's tasks are driven in end-effector space with the part held
in the gripper, so no joint vector exists to log.

Metadata records: one named `episode` holding what `start()` was given (task id, seed, policy
ids, …, all as strings) plus `env_index`, `episode`, `success`, `length`, `return`,
`truncated`, written when the episode ends.

Message log times are sim time: step `t` is logged at `t / control_hz` seconds (in ns).
"""

from __future__ import annotations

import base64
import io
import json
import os
import re
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

import numpy as np

from accrue.errors import AccrueError
from accrue.logs import mcap_schemas as S

TOPIC_STATE = "/state"
TOPIC_ACTION = "/action"
TOPIC_REWARD = "/reward"
TOPIC_REFERENCE = "/reference"
TOPIC_EE_POSE = "/ee/pose"
TOPIC_SOCKET_POSE = "/socket/pose"
TOPIC_WRENCH = "/wrist/wrench"
TOPIC_WRIST_IMAGE = "/camera/wrist"  # the image topic of the default camera name
TOPIC_LABEL = "/episode/label"

# topic -> JSON schema; the schema's title is its registered MCAP schema name
TOPIC_SCHEMAS: dict[str, dict] = {
    TOPIC_STATE: S.ACCRUE_STATE,
    TOPIC_ACTION: S.ACCRUE_ACTION,
    TOPIC_REWARD: S.ACCRUE_REWARD,
    TOPIC_REFERENCE: S.ACCRUE_REFERENCE_CHUNK,
    TOPIC_EE_POSE: S.FOXGLOVE_POSE_IN_FRAME,
    TOPIC_SOCKET_POSE: S.FOXGLOVE_POSE_IN_FRAME,
    TOPIC_WRENCH: S.ACCRUE_WRENCH,
    TOPIC_WRIST_IMAGE: S.FOXGLOVE_COMPRESSED_IMAGE,
    TOPIC_LABEL: S.ACCRUE_EPISODE_LABEL,
}
SCHEMA_NAMES: dict[str, str] = {topic: schema["title"] for topic, schema in TOPIC_SCHEMAS.items()}

METADATA_NAME = "episode"
WORLD_FRAME = "world"
_FINAL_RE = re.compile(r"^episode-(\d{6,})\.mcap$")
_PARTIAL_RE = re.compile(r"^\.episode-(\d{6,})\.mcap\.partial$")


def final_name(index: int) -> str:
    return f"episode-{index:06d}.mcap"


def partial_name(index: int) -> str:
    return f".episode-{index:06d}.mcap.partial"


def list_episodes(out_dir: Path | str) -> list[Path]:
    """Sealed episode files in `out_dir`, in episode order (temporary files are skipped)."""
    out = Path(out_dir)
    if not out.is_dir():
        return []
    return sorted(p for p in out.iterdir() if _FINAL_RE.match(p.name))


def _next_index(out_dir: Path) -> int:
    """One past the highest episode number in use, counting crashed (partial) episodes too."""
    used = [-1]
    for path in out_dir.iterdir():
        match = _FINAL_RE.match(path.name) or _PARTIAL_RE.match(path.name)
        if match:
            used.append(int(match.group(1)))
    return max(used) + 1


def _stamp(ns: int) -> dict:
    return {"sec": ns // 1_000_000_000, "nsec": ns % 1_000_000_000}


def _rotvec_to_quat_xyzw(rv: np.ndarray) -> np.ndarray:
    angle = float(np.linalg.norm(rv))
    if angle < 1e-12:
        return np.array([0.0, 0.0, 0.0, 1.0])
    axis = rv / angle
    return np.concatenate([axis * np.sin(angle / 2), [np.cos(angle / 2)]])


def pose_fields(pose: Any) -> dict:
    """Foxglove `Pose` from (3,) position, (6,) position + rotation vector, or (7,) position + quaternion xyzw."""
    p = np.asarray(pose, dtype=np.float64).reshape(-1)
    if p.size == 3:
        q = np.array([0.0, 0.0, 0.0, 1.0])
    elif p.size == 6:
        q = _rotvec_to_quat_xyzw(p[3:])
    elif p.size == 7:
        q = p[3:] / max(float(np.linalg.norm(p[3:])), 1e-12)
    else:
        raise ValueError(f"a pose has 3, 6 or 7 numbers, got {p.size}")
    return {
        "position": dict(zip("xyz", map(float, p[:3]))),
        "orientation": dict(zip("xyzw", map(float, q))),
    }


def encode_image(image: np.ndarray, fmt: str, jpeg_quality: int = 90) -> bytes:
    """HWC uint8 RGB -> jpeg/png bytes."""
    from PIL import Image

    buf = io.BytesIO()
    pil = Image.fromarray(np.ascontiguousarray(image, dtype=np.uint8))
    if fmt == "jpeg":
        pil.save(buf, format="JPEG", quality=jpeg_quality)
    else:
        pil.save(buf, format="PNG")
    return buf.getvalue()


def _as_str_map(metadata: Mapping[str, Any]) -> dict[str, str]:
    # MCAP metadata is string -> string; non-strings are stored as JSON so they read back exactly.
    return {str(k): v if isinstance(v, str) else json.dumps(v) for k, v in metadata.items()}


@dataclass
class _OpenEpisode:
    index: int
    file: IO[bytes]
    writer: Any
    temp_path: Path
    final_path: Path
    metadata: dict[str, str]
    channels: dict[str, int] = field(default_factory=dict)
    length: int = 0
    ret: float = 0.0
    last_t: int = -1


class EpisodeRecorder:
    """Records the episodes of a (vectorised) env loop, one MCAP file per episode.

    Usage from a loop over N envs::

        rec = EpisodeRecorder(out_dir, control_hz=20, state_names=STATE_NAMES)
        rec.start(i, {"task_id": ..., "seed": ..., "policy": ...})   # when env i resets
        rec.log_step(i, t, state, action, reward=r, ...)            # every step of env i
        path = rec.end(i, success=True)                             # when env i's episode ends

    Not for several processes writing into one directory at once.
    """

    def __init__(
        self,
        out_dir: Path | str,
        *,
        control_hz: float = 10.0,
        state_names: list[str] | None = None,
        image_format: str = "jpeg",
        jpeg_quality: int = 90,
        chunk_size: int = 256 * 1024,
        camera: str = "wrist",
    ) -> None:
        if image_format not in ("jpeg", "png"):
            raise AccrueError(f"image format must be jpeg or png, got {image_format!r}")
        if control_hz <= 0:
            raise AccrueError(f"control_hz must be positive, got {control_hz}")
        self.out_dir = Path(out_dir)
        self.out_dir.mkdir(parents=True, exist_ok=True)
        self.step_ns = int(round(1e9 / control_hz))
        self.state_names = list(state_names) if state_names is not None else None
        self.image_format = image_format
        self.jpeg_quality = jpeg_quality
        self.chunk_size = chunk_size
        if not re.fullmatch(r"[A-Za-z0-9_]+", camera):
            raise AccrueError(f"camera name must be letters, digits or _, got {camera!r}")
        self.camera = camera
        self.image_topic = f"/camera/{camera}"
        self._open: dict[int, _OpenEpisode] = {}
        self._next = _next_index(self.out_dir)

    # -- episode lifecycle -------------------------------------------------------------------
    def start(self, env_index: int, metadata: Mapping[str, Any] | None = None) -> None:
        """Begin a new episode for env `env_index` (an unfinished one there is discarded)."""
        from mcap.writer import CompressionType, Writer

        if env_index in self._open:
            self.abort(env_index)
        while True:  # exclusive create: never clobber a file another recorder made meanwhile
            index = self._next
            self._next += 1
            temp = self.out_dir / partial_name(index)
            if (self.out_dir / final_name(index)).exists():
                continue
            try:
                f = open(temp, "xb")
                break
            except FileExistsError:
                continue
        writer = Writer(f, chunk_size=self.chunk_size, compression=CompressionType.ZSTD)
        writer.start(profile="", library="accrue")
        self._open[env_index] = _OpenEpisode(
            index=index,
            file=f,
            writer=writer,
            temp_path=temp,
            final_path=self.out_dir / final_name(index),
            metadata=_as_str_map(metadata or {}),
        )

    def log_step(
        self,
        env_index: int,
        t: int,
        state: Any | None,
        action: Any,
        reference: Any | None = None,
        reward: float = 0.0,
        image: np.ndarray | None = None,
        ee_pose: Any | None = None,
        socket_pose: Any | None = None,
        wrench: Any | None = None,
    ) -> None:
        """Log step `t` of env `env_index`: the state seen, the action taken and the reward it got.

        Poses are (3,) position, (6,) position + rotation vector or (7,) position + quaternion
        xyzw, in the world frame; `wrench` is (6,) force then torque; `image` is HWC uint8 RGB;
        `reference` is the (H, d) reference chunk (d: the action's width) the action was refined from.
        """
        ep = self._episode(env_index)
        if t <= ep.last_t:
            raise AccrueError(f"env {env_index}: step {t} logged after step {ep.last_t}")
        ns = t * self.step_ns
        ep.ret += float(reward)
        ep.length += 1
        ep.last_t = t
        if state is not None:
            self._write(ep, TOPIC_STATE, ns, {"t": t, "values": np.asarray(state, dtype=float).reshape(-1).tolist()})
        self._write(ep, TOPIC_ACTION, ns, {"t": t, "action": np.asarray(action, dtype=float).reshape(-1).tolist()})
        self._write(ep, TOPIC_REWARD, ns, {"t": t, "reward": float(reward), "return": ep.ret})
        if reference is not None:
            chunk = np.asarray(reference, dtype=float).reshape(-1, np.size(action))  # (H, d): d as the action
            self._write(ep, TOPIC_REFERENCE, ns, {"t": t, "horizon": len(chunk), "chunk": chunk.tolist()})
        for topic, pose in ((TOPIC_EE_POSE, ee_pose), (TOPIC_SOCKET_POSE, socket_pose)):
            if pose is not None:
                msg = {"timestamp": _stamp(ns), "frame_id": WORLD_FRAME, "pose": pose_fields(pose)}
                self._write(ep, topic, ns, msg)
        if wrench is not None:
            w = np.asarray(wrench, dtype=float).reshape(-1)
            msg = {"t": t, "force": dict(zip("xyz", w[:3].tolist())), "torque": dict(zip("xyz", w[3:6].tolist()))}
            self._write(ep, TOPIC_WRENCH, ns, msg)
        if image is not None:
            data = encode_image(image, self.image_format, self.jpeg_quality)
            msg = {
                "timestamp": _stamp(ns),
                "frame_id": f"{self.camera}_camera",
                "data": base64.b64encode(data).decode("ascii"),
                "format": self.image_format,
            }
            self._write(ep, self.image_topic, ns, msg, S.FOXGLOVE_COMPRESSED_IMAGE)

    def end(
        self, env_index: int, success: bool, truncated: bool = False, metadata: Mapping[str, Any] | None = None
    ) -> Path:
        """Seal env `env_index`'s episode: label, metadata, summary, fsync, rename. Returns the file."""
        ep = self._open.pop(env_index, None)
        if ep is None:
            raise AccrueError(f"env {env_index} has no episode in progress")
        try:
            ns = max(ep.last_t, 0) * self.step_ns
            label = {"success": bool(success), "length": ep.length, "return": ep.ret, "truncated": bool(truncated)}
            self._write(ep, TOPIC_LABEL, ns, label)
            record = dict(ep.metadata)
            record.update(_as_str_map(metadata or {}))
            record.update(
                _as_str_map(
                    {
                        "env_index": env_index,
                        "episode": ep.index,
                        "success": bool(success),
                        "length": ep.length,
                        "return": ep.ret,
                        "truncated": bool(truncated),
                    }
                )
            )
            ep.writer.add_metadata(METADATA_NAME, record)
            ep.writer.finish()
            ep.file.flush()
            os.fsync(ep.file.fileno())
        except BaseException:
            ep.file.close()
            raise
        ep.file.close()
        os.replace(ep.temp_path, ep.final_path)
        _fsync_dir(self.out_dir)
        return ep.final_path

    def abort(self, env_index: int) -> None:
        """Drop env `env_index`'s unfinished episode and its temporary file."""
        ep = self._open.pop(env_index, None)
        if ep is not None:
            ep.file.close()
            ep.temp_path.unlink(missing_ok=True)

    def close(self) -> None:
        """Drop every unfinished episode (an episode that did not end is not a log)."""
        for env_index in list(self._open):
            self.abort(env_index)

    @property
    def in_progress(self) -> list[int]:
        return sorted(self._open)

    def __enter__(self) -> EpisodeRecorder:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- internals ---------------------------------------------------------------------------
    def _episode(self, env_index: int) -> _OpenEpisode:
        try:
            return self._open[env_index]
        except KeyError:
            raise AccrueError(f"env {env_index}: log_step before start") from None

    def _write(self, ep: _OpenEpisode, topic: str, ns: int, msg: dict, schema: dict | None = None) -> None:
        from mcap.well_known import MessageEncoding, SchemaEncoding

        channel = ep.channels.get(topic)
        if channel is None:
            schema = schema or TOPIC_SCHEMAS[topic]
            schema_id = ep.writer.register_schema(
                name=schema["title"], encoding=SchemaEncoding.JSONSchema, data=json.dumps(schema).encode()
            )
            chan_meta = (
                {"state_names": json.dumps(self.state_names)} if topic == TOPIC_STATE and self.state_names else {}
            )
            channel = ep.writer.register_channel(
                topic=topic, message_encoding=MessageEncoding.JSON, schema_id=schema_id, metadata=chan_meta
            )
            ep.channels[topic] = channel
        ep.writer.add_message(
            channel_id=channel, log_time=ns, publish_time=ns, data=json.dumps(msg).encode(), sequence=max(ep.last_t, 0)
        )


def _fsync_dir(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


@dataclass
class EpisodeLog:
    """One episode read back: decoded JSON messages per topic (in log-time order) and metadata."""

    messages: dict[str, list[dict]]
    schemas: dict[str, str]  # topic -> schema name
    channel_metadata: dict[str, dict[str, str]]
    metadata: dict[str, dict[str, str]]  # metadata record name -> string map

    @property
    def episode(self) -> dict[str, str]:
        return self.metadata.get(METADATA_NAME, {})

    def image(self, i: int, topic: str = TOPIC_WRIST_IMAGE) -> np.ndarray:
        """The i-th image on `topic`, decoded to HWC uint8."""
        from PIL import Image

        raw = base64.b64decode(self.messages[topic][i]["data"])
        return np.asarray(Image.open(io.BytesIO(raw)).convert("RGB"))


def read_episode(path: Path | str) -> EpisodeLog:
    """Read a sealed episode file with the `mcap` reader. A damaged file raises AccrueError."""
    from mcap.exceptions import McapError
    from mcap.reader import make_reader

    path = Path(path)
    messages: dict[str, list[dict]] = {}
    schemas: dict[str, str] = {}
    chan_meta: dict[str, dict[str, str]] = {}
    metadata: dict[str, dict[str, str]] = {}
    try:
        with open(path, "rb") as f:
            reader = make_reader(f)
            for schema, channel, message in reader.iter_messages(log_time_order=True):
                messages.setdefault(channel.topic, []).append(json.loads(message.data))
                schemas[channel.topic] = schema.name if schema is not None else ""
                chan_meta[channel.topic] = dict(channel.metadata)
            for record in reader.iter_metadata():
                metadata[record.name] = dict(record.metadata)
    except FileNotFoundError:
        raise AccrueError(f"{path}: no such episode log") from None
    except (McapError, ValueError, EOFError) as exc:
        raise AccrueError(f"{path}: not a readable MCAP episode log ({type(exc).__name__})") from None
    return EpisodeLog(messages=messages, schemas=schemas, channel_metadata=chan_meta, metadata=metadata)
