"""A small writer of rerun recordings (.rrd files) for episodes and run reports.

Each `RerunLog` owns its own `rerun.RecordingStream` (never the global one), so several logs can
be written from one process and nothing leaks between them. It only ever writes a file: no
viewer is spawned; open the file with `rerun FILE.rrd` (same rerun version, 0.26).

    with RerunLog("episode.rrd", recording_id="plugs-cross-seed0") as rl:
        rl.set_step(t)
        rl.scalar("reward", r)
        rl.pose("world/ee", xyz, quat_xyzw)
    with RerunLog("report.rrd") as rl:
        rl.curve("train/success", steps, values)          # a whole learning curve at once

`RERUN=off` in the environment disables rerun everywhere; pass `force=True` when the user asked
for this very file (e.g. `accrue sim watch --out`), so the switch does not silently drop it.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np


class RerunLog:
    """Writes one .rrd file; entity paths are plain strings like `world/ee` or `train/loss`."""

    def __init__(
        self,
        path: Path | str,
        *,
        app_id: str = "accrue",
        recording_id: str | None = None,
        timeline: str = "step",
        force: bool = False,
    ) -> None:
        import rerun as rr

        self._rr = rr
        self.path = Path(path)
        self.timeline = timeline
        self.path.parent.mkdir(parents=True, exist_ok=True)
        saved = os.environ.pop("RERUN", None) if force else None
        try:
            # rerun reads the RERUN switch when a stream is created
            self.stream = rr.RecordingStream(app_id, recording_id=recording_id)
        finally:
            if saved is not None:
                os.environ["RERUN"] = saved
        self.enabled = self.stream.is_enabled()
        if self.enabled:
            self.stream.save(str(self.path))

    def set_step(self, step: int) -> None:
        """Later calls are stamped with this value on the log's sequence timeline."""
        self.stream.set_time(self.timeline, sequence=int(step))

    def scalar(self, entity: str, value: float) -> None:
        self.stream.log(entity, self._rr.Scalars(float(value)))

    def scalars(self, prefix: str, values: dict[str, float]) -> None:
        """One scalar per key, under `prefix/key` (e.g. the six wrench components)."""
        for key, value in values.items():
            self.scalar(f"{prefix}/{key}", value)

    def pose(
        self,
        entity: str,
        translation: Sequence[float],
        quaternion_xyzw: Sequence[float] | None = None,
        *,
        radius: float = 0.004,
        color: Sequence[int] | None = None,
    ) -> None:
        """A frame (transform) at `entity` and a point marking its origin, for 3-D views."""
        rr = self._rr
        kwargs: dict[str, Any] = {"translation": np.asarray(translation, dtype=np.float32)[:3]}
        if quaternion_xyzw is not None:
            kwargs["quaternion"] = rr.Quaternion(xyzw=np.asarray(quaternion_xyzw, dtype=np.float32))
        self.stream.log(entity, rr.Transform3D(**kwargs))
        self.stream.log(f"{entity}/origin", rr.Points3D([[0.0, 0.0, 0.0]], radii=radius, colors=color))

    def points(
        self, entity: str, xyz: np.ndarray, *, radius: float = 0.002, color: Sequence[int] | None = None
    ) -> None:
        self.stream.log(
            entity, self._rr.Points3D(np.asarray(xyz, dtype=np.float32).reshape(-1, 3), radii=radius, colors=color)
        )

    def image(self, entity: str, hwc_uint8: np.ndarray, *, jpeg_quality: int = 85) -> None:
        """An RGB image, JPEG-compressed to keep the file small."""
        self.stream.log(
            entity, self._rr.Image(np.ascontiguousarray(hwc_uint8, dtype=np.uint8)).compress(jpeg_quality=jpeg_quality)
        )

    def text(self, entity: str, message: str) -> None:
        self.stream.log(entity, self._rr.TextLog(message))

    def curve(self, entity: str, steps: Sequence[int], values: Sequence[float], *, name: str | None = None) -> None:
        """A whole series in one columnar write (learning curves); independent of `set_step`."""
        rr = self._rr
        if name is not None:
            self.stream.log(entity, rr.SeriesLines(names=name), static=True)
        self.stream.send_columns(
            entity,
            indexes=[rr.TimeColumn(self.timeline, sequence=np.asarray(steps, dtype=np.int64))],
            columns=rr.Scalars.columns(scalars=np.asarray(values, dtype=np.float64)),
        )

    def close(self) -> None:
        """Flush everything to the file and detach the sink."""
        if self.enabled:
            self.stream.flush()
            self.stream.disconnect()
            self.enabled = False

    def __enter__(self) -> RerunLog:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def read_rrd_table(path: Path | str, contents: str = "/**", index: str = "step") -> dict[str, list]:
    """Columns of a recording on one timeline, as plain lists (for tests and quick checks).

    Uses rerun 0.26's dataframe API; the .rrd format is tied to the rerun version that wrote it.
    """
    import rerun.dataframe as rdf

    recording = rdf.load_recording(str(path))
    return recording.view(index=index, contents=contents).select().read_all().to_pydict()
