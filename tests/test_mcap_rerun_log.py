"""The rerun helper writes a .rrd file (never a viewer) that reads back with rerun's dataframe API."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from accrue.logs.rerun_log import RerunLog, read_rrd_table


def test_step_logging_and_curves_read_back(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("RERUN", raising=False)
    path = tmp_path / "sub" / "ep.rrd"
    with RerunLog(path, recording_id="test-1") as rl:
        for t in range(4):
            rl.set_step(t)
            rl.scalar("reward", 0.5 * t)
            rl.scalars("wrench", {"fx": t, "fz": -t})
            rl.pose("world/ee", [0.0, 0.0, 0.1 * t], [0, 0, 0, 1])
            rl.image("camera/wrist", np.full((8, 8, 3), 10 * t, np.uint8))
        rl.curve("train/success", [0, 10, 20], [0.0, 0.5, 0.9], name="success")
    assert path.stat().st_size > 0
    table = read_rrd_table(path)
    assert table["step"] == [0, 1, 2, 3, 10, 20]
    assert [v and v[0] for v in table["/reward:Scalars:scalars"]][:4] == [0.0, 0.5, 1.0, 1.5]
    assert table["/wrench/fz:Scalars:scalars"][3] == [-3.0]
    assert table["/world/ee:Transform3D:translation"][2][0] == pytest.approx([0.0, 0.0, 0.2])
    assert [v and v[0] for v in table["/train/success:Scalars:scalars"]] == [0.0, None, None, None, 0.5, 0.9]


def test_rerun_off_is_respected_unless_forced(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("RERUN", "off")
    quiet = RerunLog(tmp_path / "off.rrd")
    quiet.scalar("x", 1.0)
    quiet.close()
    assert not quiet.enabled and not (tmp_path / "off.rrd").exists()
    with RerunLog(tmp_path / "forced.rrd", force=True) as rl:
        rl.set_step(0)
        rl.scalar("x", 2.0)
    assert read_rrd_table(tmp_path / "forced.rrd")["/x:Scalars:scalars"] == [[2.0]]
    assert __import__("os").environ["RERUN"] == "off"  # the switch is restored for everyone else
