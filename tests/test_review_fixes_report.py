"""Review fix: the hardware report's intervention rate is accrue.robot.teleop.window_rate (the page's and
TensorBoard's), per block of `stop_window` consecutive train episodes and, labelled apart, sliding over the
last `stop_window` at the stage's end."""

from __future__ import annotations

import pytest


def episodes(n: int) -> list[dict]:
    # 25 episodes: the first 20 with no takeover, the last 5 driven 10 of 40 steps each
    return [
        {"index": i, "phase": "train", "control_steps": 40, "interventions": 10 if i >= 20 else 0} for i in range(n)
    ]


def test_blocks_and_the_sliding_rate_are_teleops_window_rate_and_labelled():
    from accrue.robot.teleop import window_rate
    from stages.report.hardware import intervention_rates, interventions_markdown

    eps = episodes(25)
    rows = intervention_rates(eps, 20)
    counts = [(e["interventions"], e["control_steps"]) for e in eps]
    assert [w["episodes"] for w in rows["windows"]] == ["0-19", "20-24"]
    assert [w["rate"] for w in rows["windows"]] == [0.0, 0.25]
    assert rows["windows"][1]["rate"] == pytest.approx(window_rate(counts[20:], 5))
    # the sliding rate over the last 20 (5 of them driven a quarter) is not the last block's
    assert rows["sliding_rate"] == pytest.approx(window_rate(counts, 20)) == pytest.approx(50 / 800)
    assert rows["windows_are"] == "blocks of 20 consecutive train episodes"
    assert rows["intervened_steps"] == 50

    text = interventions_markdown({1: rows})
    assert "| stage | block of episodes |" in text and "| 1 | 20-24 | 50 | 200 | 5 | 25.0% |" in text
    assert "- stage 1: per block of 20; sliding over the last 20 at the end: 6.2%" in text
