"""robot.success_classifier in a session: who labels each episode - the operator, the operator confirming
the classifier's proposal, or the classifier alone above robot.success_classifier.auto_label_above - and
the step's `success_classifier` output (accrue.robot.success_classifier is the model itself).

Every episode the classifier was consulted on says so in its sealed episode.json: `classifier` {mode, p,
trained_on} and, on the simulated robot, `sim_success` (the simulator's own outcome, for the audit only).
Modes: held-out (the operator labels, the classifier is not consulted: these measure it), untrained (fewer
than min_labels operator labels of both outcomes yet), proposed (the operator confirmed or overruled its
proposal), operator (below the threshold with propose off), auto (it labelled alone, by: "classifier").
It trains on the step's operator-labelled episodes that are not held out; never on its own labels.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from accrue.robot.success_classifier import ClassifierSettings, Model, confident, fit, held_out, inputs_of, scores
from stages.errors import StageError
from stages.steps.common import write_json

OUTPUT = "success_classifier"
KIND = "success-classifier"
NOT_OPERATOR = ("classifier", "system")  # labels no person gave


class ClassifierGate:
    def __init__(self, settings: ClassifierSettings, session, encoder_spec: str, phase: str):
        self.settings, self.session, self.encoder_spec, self.phase = settings, session, encoder_spec, phase
        self.image_width: int | None = None
        self.state_width = 0
        self.model: Model | None = None
        self.trained_on: list[int] = []
        self._key: tuple | None = None
        self._rows: dict[int, np.ndarray] = {}

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

    def training(self) -> list[tuple[dict, np.ndarray]]:
        rows = []
        for e in self.judged():
            if e["classifier"]["mode"] == "held-out" or e["label"]["by"] in NOT_OPERATOR:
                continue
            x = self.row(e["index"])
            if x is not None:
                rows.append((e, x))
        return rows

    def refresh(self) -> None:
        """(Re)fit on the operator labels sealed so far, when they changed and there are enough of both outcomes."""
        rows = self.training()
        key = tuple((e["index"], bool(e["label"]["success"])) for e, _ in rows)
        if key == self._key:
            return
        self._key = key
        labels = [bool(e["label"]["success"]) for e, _ in rows]
        if len(rows) < self.settings.min_labels or all(labels) or not any(labels):
            self.model, self.trained_on = None, []
            return
        self.model = fit(np.stack([x for _, x in rows]), np.array(labels))
        self.trained_on = [e["index"] for e, _ in rows]

    # ------------------------------------------------------------------ labelling one episode
    def label(self, index: int, summary: str, s_last: np.ndarray, operator) -> tuple:
        """(Label or None when the operator aborted, the episode record's `classifier` entry)."""
        from accrue.robot.operator import Label, now_iso

        asked = sum(e["classifier"]["mode"] != "auto" for e in self.judged())  # operator-labelled so far
        if held_out(asked, self.settings.holdout):
            return operator.label(index, summary), {"mode": "held-out", "p": None, "trained_on": 0}
        self.refresh()
        if self.model is None:
            return operator.label(index, summary), {"mode": "untrained", "p": None, "trained_on": 0}
        x = inputs_of(s_last, self.image_width, self.state_width, self.settings.state)
        p = float(self.model.predict(x[None])[0])
        entry = {"p": round(p, 6), "trained_on": len(self.trained_on)}
        above = self.settings.auto_label_above
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
        with its final p, precision and recall) and inputs.npy (those episodes' rows, in the same order)."""
        self.refresh()
        out = ctx.new_output(OUTPUT, KIND)
        entries, rows = [], []
        for e in self.judged():
            x = self.row(e["index"])
            if x is None:
                continue
            p = None if self.model is None else round(float(self.model.predict(x[None])[0]), 6)
            entries.append(
                {
                    "index": e["index"],
                    "mode": e["classifier"]["mode"],
                    "label": bool(e["label"]["success"]),
                    "label_by": e["label"]["by"],
                    "p": p,
                    "sim_success": e.get("sim_success"),
                }
            )
            rows.append(x)
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
                "episodes": entries,
                "metrics": metrics(entries),
            },
        )
        return out


def metrics(entries: list[dict]) -> dict:
    """Precision / recall (success positive) of the final model on the held-out episodes against the
    operator's labels and, where the simulator said, against its own success; and of the classifier's
    own labels against the simulator."""
    held = [e for e in entries if e["mode"] == "held-out" and e["p"] is not None]
    pred = [e["p"] >= 0.5 for e in held]
    out = {"held_out_vs_operator": scores(pred, [e["label"] for e in held])}
    if held and all(e["sim_success"] is not None for e in held):
        out["held_out_vs_simulator"] = scores(pred, [e["sim_success"] for e in held])
    auto = [e for e in entries if e["label_by"] == "classifier"]
    if auto and all(e["sim_success"] is not None for e in auto):
        out["auto_labels_vs_simulator"] = scores([e["label"] for e in auto], [e["sim_success"] for e in auto])
    out["labels"] = {mode: sum(e["mode"] == mode for e in entries) for mode in sorted({e["mode"] for e in entries})}
    return out
