"""robot.success_classifier in a session: who labels each episode - the operator, the operator confirming
the classifier's proposal, or the classifier alone above robot.success_classifier.auto_label_above - and
the step's `success_classifier` output (accrue.robot.success_classifier is the model itself).

Every episode the classifier was consulted on says so in its sealed episode.json: `classifier` {mode, p,
trained_on} and, on the simulated robot, `sim_success` (the simulator's own outcome, for the audit only).
Modes: held-out (the operator labels, the classifier is not consulted: these measure it), untrained (fewer
than min_labels operator labels of both outcomes yet), proposed (the operator confirmed or overruled its
proposal), operator (below the threshold with propose off), auto (it labelled alone, by: "classifier"),
audit (it would have labelled alone, but this is the audit_every-th such episode: the operator labels it
blind and it joins the held-out set). It trains on operator labels that are neither held out nor audits;
never on its own labels.

Within a stage the train step starts from what the operator taught it in warmup: its `warmup-classifier`
input (warmup's `success_classifier` artifact, wired by stages.steps.robot_plan, so train's cache key and
lineage name it) gives warmup's judged episodes and their rows; warmup's trainable labels are in train's
training set from its first episode, warmup's held-out episodes stay held out (and are measured again by
train's final classifier), and the held-out share and the audit count go on from warmup's. Nothing is carried
across stages: each stage's warmup starts from nothing. All of it is a function of the sealed episodes (and
that input), so a step resumed with --continue decides as an uninterrupted one would.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from accrue.robot.success_classifier import (
    ClassifierSettings,
    Model,
    audited,
    confident,
    fit,
    held_out,
    inputs_of,
    scores,
)
from stages.errors import StageError
from stages.steps.common import write_json

OUTPUT = "success_classifier"
KIND = "success-classifier"
NOT_OPERATOR = ("classifier", "system")  # labels no person gave
CARRIED = "warmup-classifier"  # train's input role: the stage's warmup `success_classifier` artifact
HELD_OUT = ("held-out", "audit")  # the operator labelled them blind; never trained on: they measure it
NOT_ASKED = ("auto", "audit")  # not counted in the held-out share (audits are held out on their own count)


class ClassifierGate:
    def __init__(self, settings: ClassifierSettings, session, encoder_spec: str, phase: str):
        self.settings, self.session, self.encoder_spec, self.phase = settings, session, encoder_spec, phase
        self.image_width: int | None = None
        self.state_width = 0
        self.model: Model | None = None
        self.trained_on: list[list] = []  # [phase, index] of each label the model was fitted on
        self._key: tuple | None = None
        self._rows: dict[int, np.ndarray] = {}
        self.carried: list[dict] = []  # warmup's judged episodes (train, from its CARRIED input)
        self.carried_rows = np.zeros((0, 0), np.float32)
        self.carried_from: str | None = None  # that artifact's id

    def carry(self, artifact_dir: Path, artifact_id: str) -> None:
        """Start from the stage's warmup classifier: its judged episodes (labels, modes) and their rows."""
        import json

        data = json.loads((artifact_dir / "classifier.json").read_text())
        mine = {"encoder": self.encoder_spec, "state": self.settings.state}
        theirs = {"encoder": data["inputs"]["encoder"], "state": data["settings"]["state"]}
        if mine != theirs:
            raise StageError(
                f"robot.success_classifier: the warmup classifier {artifact_id[:12]} read {theirs}, this step "
                f"reads {mine}; rerun the stage's warmup"
            )
        rows = np.load(artifact_dir / "inputs.npy")
        if len(rows) != len(data["episodes"]):
            raise StageError(
                f"robot.success_classifier: the warmup classifier {artifact_id[:12]} has {len(rows)} input rows "
                f"for {len(data['episodes'])} episodes"
            )
        self.carried = [{**e, "phase": e.get("phase", data["phase"])} for e in data["episodes"]]
        self.carried_rows, self.carried_from = rows, artifact_id

    def bind(self, mapping) -> None:
        """The robot is connected: the width of E(I) over its cameras and of q, in the learner's s."""
        if not mapping.camera_keys:
            raise StageError(
                "robot.success_classifier: the robot has no cameras, and the classifier reads E(I) of the "
                "episode's last frame; set robot.camera_keys (or turn the classifier off)"
            )
        if self.image_width is None:
            from accrue.encoders import make_encoder

            self.image_width = make_encoder(self.encoder_spec).feature_dim * len(mapping.camera_keys)
        self.state_width = len(mapping.state_keys)
        width = self.image_width + (self.state_width if self.settings.state else 0)
        if len(self.carried_rows) and self.carried_rows.shape[1] != width:
            raise StageError(
                f"robot.success_classifier: the warmup classifier's rows are {self.carried_rows.shape[1]} wide, "
                f"this robot's are {width} (cameras or state keys changed?); rerun the stage's warmup"
            )

    # ------------------------------------------------------------------ the episodes it reads
    def row(self, index: int) -> np.ndarray | None:
        if index not in self._rows:
            s = self.session.arrays(index)["s"]
            if not len(s):
                return None
            self._rows[index] = inputs_of(s[-1], self.image_width, self.state_width, self.settings.state)
        return self._rows[index]

    def judged(self) -> list[dict]:
        """This step's episodes the classifier was consulted on (labelled by the operator or by it)."""
        return [e for e in self.session.ordered(self.phase) if "classifier" in e]

    def modes(self) -> list[str]:
        """The mode of every episode judged so far in the stage: warmup's carried ones, then this step's."""
        return [e["mode"] for e in self.carried] + [e["classifier"]["mode"] for e in self.judged()]

    def training(self) -> list[tuple[tuple[str, int], bool, np.ndarray]]:
        """((phase, index), label, row) of each operator label it trains on: warmup's carried ones first."""
        rows = [
            ((e["phase"], e["index"]), bool(e["label"]), x)
            for e, x in zip(self.carried, self.carried_rows)
            if e["mode"] not in HELD_OUT and e["label_by"] not in NOT_OPERATOR
        ]
        for e in self.judged():
            if e["classifier"]["mode"] in HELD_OUT or e["label"]["by"] in NOT_OPERATOR:
                continue
            x = self.row(e["index"])
            if x is not None:
                rows.append(((self.phase, e["index"]), bool(e["label"]["success"]), x))
        return rows

    def refresh(self) -> None:
        """(Re)fit on the operator labels sealed so far, when they changed and there are enough of both outcomes."""
        rows = self.training()
        key = tuple((at, label) for at, label, _ in rows)
        if key == self._key:
            return
        self._key = key
        labels = [label for _, label, _ in rows]
        if len(rows) < self.settings.min_labels or all(labels) or not any(labels):
            self.model, self.trained_on = None, []
            return
        self.model = fit(np.stack([x for _, _, x in rows]), np.array(labels))
        self.trained_on = [list(at) for at, _, _ in rows]

    # ------------------------------------------------------------------ labelling one episode
    def label(self, index: int, summary: str, s_last: np.ndarray, operator) -> tuple:
        """(Label or None when the operator aborted, the episode record's `classifier` entry)."""
        from accrue.robot.operator import Label, now_iso

        modes = self.modes()
        asked = sum(m not in NOT_ASKED for m in modes)  # operator labels so far in the stage, audits aside
        if held_out(asked, self.settings.holdout):
            return operator.label(index, summary), {"mode": "held-out", "p": None, "trained_on": 0}
        self.refresh()
        if self.model is None:
            return operator.label(index, summary), {"mode": "untrained", "p": None, "trained_on": 0}
        x = inputs_of(s_last, self.image_width, self.state_width, self.settings.state)
        p = float(self.model.predict(x[None])[0])
        entry = {"p": round(p, 6), "trained_on": len(self.trained_on)}
        above = self.settings.auto_label_above
        if confident(p, above) and audited(sum(m in NOT_ASKED for m in modes), self.settings.audit_every):
            operator.tell(f"episode {index}: the classifier is sure (p(success) {p:.3f}); a spot check: label it")
            return operator.label(index, summary), {"mode": "audit", **entry}
        if confident(p, above):
            word = "success" if p >= 0.5 else "failure"
            operator.tell(f"episode {index} labelled {word} by the classifier (p(success) {p:.3f})")
            note = f"p(success) {p:.6f}; confidence above robot.success_classifier.auto_label_above {above:g}"
            label = Label(success=p >= 0.5, by="classifier", at=now_iso(), note=note, via="classifier")
            return label, {"mode": "auto", **entry}
        if self.settings.propose:
            return operator.label_proposed(index, summary, p >= 0.5, p), {"mode": "proposed", **entry}
        return operator.label(index, summary), {"mode": "operator", **entry}

    # ------------------------------------------------------------------ the step's output
    def write_output(self, ctx) -> Path:
        """`success_classifier`: classifier.json (settings, inputs, the final model, each consulted episode
        with its final p, precision and recall) and inputs.npy (those episodes' rows, in the same order);
        in train, warmup's carried episodes come first (phase: warmup), with the p of this final model."""
        self.refresh()
        out = ctx.new_output(OUTPUT, KIND)
        entries, rows = [dict(e) for e in self.carried], list(self.carried_rows)
        for e in self.judged():
            x = self.row(e["index"])
            if x is None:
                continue
            entries.append(
                {
                    "phase": self.phase,
                    "index": e["index"],
                    "mode": e["classifier"]["mode"],
                    "label": bool(e["label"]["success"]),
                    "label_by": e["label"]["by"],
                    "sim_success": e.get("sim_success"),
                }
            )
            rows.append(x)
        # every judged episode (warmup's carried ones too) with the p of this final model, in one pass
        ps = self.model.predict(np.stack(rows)) if self.model is not None and rows else [None] * len(rows)
        for e, p in zip(entries, ps):
            e["p"] = None if p is None else round(float(p), 6)
        np.save(out / "inputs.npy", np.stack(rows) if rows else np.zeros((0, 0), np.float32))
        write_json(
            out / "classifier.json",
            {
                "phase": self.phase,
                "settings": self.settings.__dict__,
                "inputs": {
                    "encoder": self.encoder_spec,
                    "frame": "last",
                    "image_width": self.image_width,
                    "state_width": self.state_width if self.settings.state else 0,
                },
                "model": None if self.model is None else self.model.to_json(),
                "trained_on": self.trained_on,
                "carried": None
                if self.carried_from is None
                else {"from": self.carried_from, "episodes": len(self.carried)},
                "episodes": entries,
                "metrics": metrics(entries, self.phase),
            },
        )
        return out


def metrics(entries: list[dict], phase: str) -> dict:
    """Precision / recall (success positive) of the final model on the held-out episodes (held-out and
    audit, warmup's carried ones included) against the operator's labels and, where the simulator said,
    against its own success; and of the classifier's own labels (this step's) against the simulator."""
    held = [e for e in entries if e["mode"] in HELD_OUT and e["p"] is not None]
    pred = [e["p"] >= 0.5 for e in held]
    out = {"held_out_vs_operator": scores(pred, [e["label"] for e in held])}
    if held and all(e["sim_success"] is not None for e in held):
        out["held_out_vs_simulator"] = scores(pred, [e["sim_success"] for e in held])
    own = [e for e in entries if e["phase"] == phase]
    auto = [e for e in own if e["label_by"] == "classifier"]
    if auto and all(e["sim_success"] is not None for e in auto):
        out["auto_labels_vs_simulator"] = scores([e["label"] for e in auto], [e["sim_success"] for e in auto])
    out["labels"] = _count(own)
    carried = [e for e in entries if e["phase"] != phase]
    if carried:
        out["carried_labels"] = _count(carried)
    return out


def _count(entries: list[dict]) -> dict:
    return {mode: sum(e["mode"] == mode for e in entries) for mode in sorted({e["mode"] for e in entries})}
