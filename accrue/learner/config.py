"""LearnerConfig: every knob of the chunked actor-critic and of the continual rule, JSON-able.

The workflow YAML's `learner:` section is parsed into this dataclass with `LearnerConfig.from_dict`.
A bad value raises AccrueError naming the field. Defaults are the small CPU configuration (a stage's
RL fits in a few minutes on 2 cores); `LearnerConfig.paper()` gives the paper-scale GPU sizes
(FastSAC 768/512 hidden, batch 8192, H = 16 is the caller's horizon).
"""

from __future__ import annotations

import dataclasses
import math
import reprlib
from dataclasses import dataclass, field

from accrue.errors import AccrueError
from accrue.methods import ABLATIONS, METHODS, MethodRules, rules

ALGOS = ("fasttd3", "fastsac")
# Eq. 4's student inputs: the stored (s_j, ã_j) as written (the paper), the current base policy's fresh
# chunk at s_j, or both (accrue's option against reference shift; see docs/DEPARTURES.md)
DISTILL_INPUTS = ("stored", "fresh", "both")
# When the observation normaliser's statistics move: during the learner's first stage only (then frozen,
# so teacher, student, EWC anchor and RETAIN's θ_prev read s through one fixed map), or every stage
OBS_NORM_UPDATES = ("first-stage", "every-stage")
EXPLORATIONS = ("white", "ou")  # FastTD3's per-step noise; noise correlated over `noise_steps` control steps


@dataclass
class LearnerConfig:
    algo: str = "fasttd3"  # "fasttd3" (deterministic + noise) or "fastsac" (tanh-Gaussian)
    method: str = "accrue"  # continual rule, one of METHODS
    ablation: str = "none"  # one of ABLATIONS (only with method "accrue")
    seed: int = 0

    # networks
    actor_hidden: list[int] = field(default_factory=lambda: [256, 256])
    critic_hidden: list[int] = field(default_factory=lambda: [256, 256])
    projector_dim: int = 64  # each network's own trainable projector of s
    layer_norm: bool = True
    actor_residual: bool = True  # a = tanh(atanh(ã) + δ): start at the reference (see networks.py)
    actor_init_scale: float = 0.01  # last actor layer init scale (FastTD3), so δ ≈ 0 at start
    # |δ| ≤ delta_bound per action dimension in pre-tanh space (δ = b·tanh(δ_raw / b)); 0 = unbounded (the paper)
    delta_bound: float = 0.0
    ref_dropout: float = 0.1  # fraction p of each batch whose ã is replaced by zeros

    # categorical critic (C51, Eq. 2)
    num_atoms: int = 101
    v_min: float = -1.0  # sparse returns lie in [0, ~3]; a margin on both sides
    v_max: float = 4.0
    gamma: float = 0.99
    n_step: int = 1  # chunk transitions per bootstrap (1 = the paper's H-step backup)
    use_cdq: bool = True  # clipped double-Q: target dist with the smaller expectation
    tau: float = 0.1  # Polyak rate of the target critic

    # optimisation
    batch_size: int = 256
    utd: int = 2  # gradient updates per chunk env step
    policy_frequency: int = 2  # actor update every n-th critic update
    actor_lr: float = 1e-3  # CPU stages are short; the paper-scale config uses 3e-4
    critic_lr: float = 1e-3
    weight_decay: float = 0.1  # AdamW
    max_grad_norm: float = 0.0  # 0 = no clipping (FastTD3's default); both networks' gradients
    learning_starts: int = 0  # no update (critic, actor, normaliser) while B^k holds fewer transitions
    # no actor update while B^k holds fewer transitions (the critic learns the reference's value first, so
    # the actor's first steps follow a critic fitted to this task's data; 0 = the paper: both from the start)
    actor_learning_starts: int = 0
    obs_normalization: bool = True  # running mean/std of s, part of the saved state
    obs_norm_update: str = "first-stage"  # one of OBS_NORM_UPDATES ("every-stage" = before issue 10)
    obs_norm_min_std: float = 0.1  # std floor: a column constant so far (a task code) cannot blow up
    obs_norm_clip: float = 10.0  # |z| clip after normalising (0 = none)
    # the last N columns of s have a fixed known scale (a task descriptor) and are never normalised (0 = none;
    # the plan sets it from the workflow's task_descriptor)
    obs_norm_fixed_tail: int = 0

    # exploration
    std_min: float = 0.001  # FastTD3: per-env noise std drawn in [std_min, std_max]
    std_max: float = 0.2
    # "white": a fresh Gaussian every control step (FastTD3); "ou": an Ornstein-Uhlenbeck process per env
    # and action dimension with time constant noise_steps control steps, carried across chunks, restarted
    # from its stationary law when the env resets (the same per-env std scales it)
    exploration: str = "white"
    noise_steps: float = 16.0
    policy_noise: float = 0.001  # FastTD3 target-policy smoothing
    noise_clip: float = 0.5
    alpha_init: float = 0.01  # FastSAC temperature
    alpha_lr: float = 3e-4
    target_entropy_per_dim: float = -1.0
    log_std_min: float = -5.0
    log_std_max: float = 0.0

    # losses and continual rule (Eqs. 1, 4, 5)
    beta: float = 0.1  # Eq. 1 anchor β‖a − ã‖²
    # β ramps linearly from beta_start down (or up) to beta over each stage's first beta_anneal_updates actor
    # updates: the anchor holds the actor at ã while the new task's critic knows only actions near it
    # (0 = a constant β, the paper)
    beta_start: float = 1.0
    beta_anneal_updates: int = 0
    lam: float = 1.0  # Eq. 5 distillation weight λ
    distill_inputs: str = "stored"  # one of DISTILL_INPUTS; "stored" is Eq. 3-4 as written
    ewc_lambda: float = 100.0  # EWC penalty weight
    ewc_samples: int = 1024  # transitions used to estimate the Fisher at handoff
    retain_alpha: float = 0.5  # RETAIN: θ ← (1−α)·θ_prev + α·θ_cur
    retain_interval: int = 0  # RETAIN: also merge every n actor updates (0 = end of stage only)

    # speed (GPU only; ignored on CPU)
    device: str = "cpu"
    amp: bool = False  # bf16 autocast
    compile: bool = False  # torch.compile of the critic and actor loss functions
    compile_mode: str = "default"  # "reduce-overhead" = CUDA graphs

    # ---- construction / validation -------------------------------------------------------
    def __post_init__(self) -> None:
        self.validate()

    @classmethod
    def paper(cls, **overrides) -> "LearnerConfig":
        """The paper-scale GPU configuration (FastSAC sizes, batch 8192, γ = 0.997)."""
        base = dict(
            algo="fastsac",
            actor_hidden=[512, 256, 128],
            critic_hidden=[768, 384, 192],
            projector_dim=256,
            batch_size=8192,
            utd=8,
            policy_frequency=4,
            gamma=0.997,
            tau=0.125,
            weight_decay=0.001,
            alpha_init=0.001,
            actor_lr=3e-4,
            critic_lr=3e-4,
            device="cuda",
            amp=True,
            compile=True,
        )
        base.update(overrides)
        return cls(**base)

    @classmethod
    def from_dict(cls, data: dict) -> "LearnerConfig":
        if not isinstance(data, dict):
            raise AccrueError(f"learner: expected a mapping, got {type(data).__name__}")
        known = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(data) - known)
        if unknown:
            raise AccrueError(f"learner.{unknown[0]}: unknown setting")
        return cls(**data)

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)

    def replace(self, **changes) -> "LearnerConfig":
        return dataclasses.replace(self, **changes)

    def validate(self) -> None:
        def bad(name: str, why: str) -> AccrueError:
            got = reprlib.repr(getattr(self, name))  # bounded per level; nested values still add up
            got = got if len(got) <= 200 else got[:199] + "…"
            return AccrueError(f"learner.{name}: {why} (got {got})")

        for name in ("algo", "method", "ablation", "distill_inputs", "obs_norm_update", "exploration"):
            allowed = {
                "exploration": EXPLORATIONS,
                "algo": ALGOS,
                "method": METHODS,
                "ablation": ABLATIONS,
                "distill_inputs": DISTILL_INPUTS,
                "obs_norm_update": OBS_NORM_UPDATES,
            }[name]
            if getattr(self, name) not in allowed:
                raise bad(name, f"must be one of {', '.join(allowed)}")
        if self.exploration == "ou" and self.algo != "fasttd3":
            raise bad("exploration", "'ou' is FastTD3's (fastsac samples from its own Gaussian policy)")
        if self.ablation != "none" and self.method != "accrue":
            raise bad("ablation", "ablations apply to method 'accrue' only")
        for name in ("actor_hidden", "critic_hidden"):
            v = getattr(self, name)
            if isinstance(v, tuple):
                setattr(self, name, list(v))
                v = getattr(self, name)
            if (
                not isinstance(v, list)
                or not v
                or not all(isinstance(h, int) and not isinstance(h, bool) and h > 0 for h in v)
            ):
                raise bad(name, "must be a non-empty list of positive integers")
        positive_ints = ("projector_dim", "num_atoms", "n_step", "batch_size", "utd", "policy_frequency", "ewc_samples")
        for name in positive_ints:
            v = getattr(self, name)
            if not isinstance(v, int) or isinstance(v, bool) or v < 1:
                raise bad(name, "must be a positive integer")
        if self.num_atoms < 2:
            raise bad("num_atoms", "needs at least 2 atoms")
        for name in (
            "seed",
            "retain_interval",
            "learning_starts",
            "actor_learning_starts",
            "obs_norm_fixed_tail",
            "beta_anneal_updates",
        ):
            v = getattr(self, name)
            if not isinstance(v, int) or isinstance(v, bool) or v < 0:
                raise bad(name, "must be a non-negative integer")
        floats = (
            "v_min",
            "v_max",
            "gamma",
            "tau",
            "actor_lr",
            "critic_lr",
            "weight_decay",
            "max_grad_norm",
            "std_min",
            "std_max",
            "noise_steps",
            "delta_bound",
            "policy_noise",
            "noise_clip",
            "alpha_init",
            "alpha_lr",
            "target_entropy_per_dim",
            "log_std_min",
            "log_std_max",
            "beta",
            "beta_start",
            "lam",
            "ewc_lambda",
            "retain_alpha",
            "ref_dropout",
            "actor_init_scale",
            "obs_norm_min_std",
            "obs_norm_clip",
        )
        for name in floats:
            v = getattr(self, name)
            if isinstance(v, str):  # PyYAML reads "1e-3" (no dot) as a string
                try:
                    v = float(v)
                except ValueError:
                    raise bad(name, "must be a number") from None
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):  # no nan/inf
                raise bad(name, "must be a finite number")
            setattr(self, name, float(v))
        if self.v_max <= self.v_min:
            raise bad("v_max", "must be greater than v_min")
        if not 0.0 < self.gamma <= 1.0:
            raise bad("gamma", "must be in (0, 1]")
        if not 0.0 < self.tau <= 1.0:
            raise bad("tau", "must be in (0, 1]")
        if not 0.0 <= self.ref_dropout <= 1.0:
            raise bad("ref_dropout", "must be in [0, 1]")
        if not 0.0 <= self.retain_alpha <= 1.0:
            raise bad("retain_alpha", "must be in [0, 1]")
        for name in ("actor_lr", "critic_lr", "alpha_lr", "alpha_init", "actor_init_scale"):
            if getattr(self, name) <= 0:
                raise bad(name, "must be positive")
        for name in (
            "weight_decay",
            "max_grad_norm",
            "std_min",
            "policy_noise",
            "noise_clip",
            "beta",
            "beta_start",
            "lam",
            "ewc_lambda",
            "obs_norm_min_std",
            "obs_norm_clip",
            "delta_bound",
        ):
            if getattr(self, name) < 0:
                raise bad(name, "must be non-negative")
        if self.noise_steps < 1:
            raise bad("noise_steps", "must be at least 1 control step")
        if self.std_max < self.std_min:
            raise bad("std_max", "must be >= std_min")
        if self.log_std_max <= self.log_std_min:
            raise bad("log_std_max", "must be greater than log_std_min")
        for name in ("layer_norm", "actor_residual", "use_cdq", "obs_normalization", "amp", "compile"):
            if not isinstance(getattr(self, name), bool):
                raise bad(name, "must be true or false")
        if self.compile_mode not in ("default", "reduce-overhead", "max-autotune"):
            raise bad("compile_mode", "must be one of default, reduce-overhead, max-autotune")
        if not isinstance(self.device, str) or not (self.device == "cpu" or self.device.startswith("cuda")):
            raise bad("device", "must be 'cpu' or 'cuda[:n]'")

    # ---- derived rules -------------------------------------------------------------------
    @property
    def rules(self) -> MethodRules:
        """The continual method's rules with the ablation applied (accrue.methods)."""
        return rules(self.method, self.ablation)

    @property
    def effective_beta(self) -> float:
        return 0.0 if self.rules.zero_beta else self.beta
