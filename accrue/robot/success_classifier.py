"""A learned success classifier for robot episodes (HIL-SERL's reward classifier, off by default).

    model = fit(X, y)                      # logistic regression on standardised inputs (torch, LBFGS)
    p = model.predict(X)                   # P(success) per row
    model.to_json() / Model.from_json(d)   # plain numbers: the artifact is readable without torch
    held_out(j, 0.25)                      # is the j-th operator-labelled episode kept from training?
    audited(n, 10)                         # does the n-th episode it would label alone go to the operator?
    scores(pred, truth)                    # precision / recall with their counts

The input is one row per episode: the frozen encoder's features E(I) of the episode's last frame, and its q
when asked (`inputs_of`). A linear head, because an operator gives dozens of labels, not thousands: a
deeper head on frozen features would learn the labels by heart. Nothing here knows about sessions or the
store (stages.steps.robot_classifier drives it).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

L2 = 1e-2  # ridge on the weights: few labels, hundreds of feature columns
STEPS = 100  # LBFGS iterations; a convex problem this small converges well within them


@dataclass(frozen=True)
class ClassifierSettings:
    """robot.success_classifier (stages.workflow.SuccessClassifierSpec) as the session reads it."""

    enabled: bool = False
    min_labels: int = 8
    propose: bool = True
    auto_label_above: float | None = None
    holdout: float = 0.25
    audit_every: int | None = 10
    state: bool = False

    @classmethod
    def from_dict(cls, d: dict | None) -> "ClassifierSettings":
        return cls(**(d or {}))


@dataclass(frozen=True)
class Model:
    mean: np.ndarray  # (D,) standardisation fitted on the training rows
    scale: np.ndarray  # (D,)
    w: np.ndarray  # (D,)
    b: float

    def predict(self, X: np.ndarray) -> np.ndarray:
        z = ((np.asarray(X, np.float64) - self.mean) / self.scale) @ self.w + self.b
        return 1.0 / (1.0 + np.exp(-np.clip(z, -60, 60)))

    def to_json(self) -> dict:
        return {"mean": self.mean.tolist(), "scale": self.scale.tolist(), "w": self.w.tolist(), "b": self.b}

    @classmethod
    def from_json(cls, d: dict) -> "Model":
        arr = lambda k: np.asarray(d[k], dtype=np.float64)  # noqa: E731
        return cls(arr("mean"), arr("scale"), arr("w"), float(d["b"]))


def fit(X: np.ndarray, y: np.ndarray) -> Model:
    """Logistic regression, L2-penalised, from zero weights: the same rows give the same model."""
    import torch

    X = np.asarray(X, np.float64)
    y = np.asarray(y, np.float64)
    mean = X.mean(axis=0)
    scale = X.std(axis=0)
    scale[scale < 1e-8] = 1.0  # a constant column (a camera that did not change) carries nothing
    xs = torch.from_numpy((X - mean) / scale)
    ys = torch.from_numpy(y)
    w = torch.zeros(X.shape[1], dtype=torch.float64, requires_grad=True)
    b = torch.zeros((), dtype=torch.float64, requires_grad=True)
    opt = torch.optim.LBFGS([w, b], max_iter=STEPS, line_search_fn="strong_wolfe")

    def loss():
        opt.zero_grad()
        value = torch.nn.functional.binary_cross_entropy_with_logits(xs @ w + b, ys) + L2 * (w * w).sum()
        value.backward()
        return value

    opt.step(loss)
    return Model(mean, scale, w.detach().numpy().copy(), float(b.detach()))


def held_out(j: int, fraction: float) -> bool:
    """Whether the j-th (0-based) operator-labelled episode is held out: evenly spread, so a share
    `fraction` of any prefix is held out, and an episode's status never changes as more come."""
    return fraction > 0 and math.floor((j + 1) * fraction) > math.floor(j * fraction)


def inputs_of(s_last: np.ndarray, image_width: int, state_width: int, state: bool) -> np.ndarray:
    """The classifier's row from the learner's s of the last frame, (E(I_1) ... E(I_m), q, ...)."""
    s_last = np.asarray(s_last, np.float32)
    return s_last[: image_width + (state_width if state else 0)]


def audited(n: int, every: int | None) -> bool:
    """Whether the n-th (0-based) episode the classifier would label alone goes to the operator anyway
    (robot.success_classifier.audit_every): every `every`-th one, the last of each run of `every`."""
    return every is not None and (n + 1) % every == 0


def confident(p: float, above: float | None) -> bool:
    """The classifier may label alone: its confidence in the more likely outcome is above the threshold."""
    return above is not None and max(p, 1.0 - p) > above


def scores(pred: list[bool], truth: list[bool]) -> dict:
    """Precision and recall of `pred` against `truth` (success is the positive class); None where undefined."""
    tp = sum(p and t for p, t in zip(pred, truth))
    fp = sum(p and not t for p, t in zip(pred, truth))
    fn = sum(t and not p for p, t in zip(pred, truth))
    return {
        "episodes": len(truth),
        "tp": tp,
        "fp": fp,
        "fn": fn,
        "tn": len(truth) - tp - fp - fn,
        "precision": round(tp / (tp + fp), 4) if tp + fp else None,
        "recall": round(tp / (tp + fn), 4) if tp + fn else None,
    }
