"""Every continual method's rules, in one table (paper Sec. IV and the baselines of Sec. V-A, Table IV).

A method is a row: what the stage inherits, which data the critic and the Eq. 1 objective read, whether
the actor is distilled toward cached Eq. 3 targets (Eq. 4–5), and the baseline-specific extras. The
learner (`accrue.learner`), the stage loop and the steps all ask `rules(method, ablation)`; nothing
else branches on a method's name. A new baseline is one row here. Torch-free, so the workflow
validator can import it at CLI start-up.
"""

from __future__ import annotations

from dataclasses import dataclass, replace


@dataclass(frozen=True)
class MethodRules:
    inherit_actor: bool = True  # θ^k starts from θ^{k-1} (else fresh, seeded by stage)
    inherit_critic: bool = True  # ψ^k starts from ψ^{k-1}
    critic_on_prior: bool = False  # critic TD (Eq. 2) also on B^{<k}
    actor_rl_on_prior: bool = False  # Eq. 1 also on B^{<k}
    distill: bool = False  # Eq. 4 on B^{<k} toward cached Eq. 3 targets, weighted by λ (Eq. 5)
    uses_prior_memory: bool = False  # samples B^{<k} at all during a stage
    ewc_penalty: bool = False  # EWC: Fisher-weighted anchor to θ^{k-1}
    merge: bool = False  # RETAIN: deploy (1−α)·θ_prev + α·θ (discounted interpolation)
    checkpoint_per_task: bool = False  # Isolated: task i is served by the learner kept after stage i
    use_reference: bool = True  # actor and critic see ã (no-reference ablation: π_θ(s), Q(s, a))
    zero_beta: bool = False  # β = 0 ablation of Eq. 1

    @property
    def critic_data(self) -> str:
        return "current+prior" if self.critic_on_prior else "current"

    @property
    def actor_rl_data(self) -> str:
        return "current+prior" if self.actor_rl_on_prior else "current"


_ACCRUE = MethodRules(distill=True, uses_prior_memory=True)

METHOD_RULES: dict[str, MethodRules] = {
    "accrue": _ACCRUE,
    "sequential": MethodRules(),
    "er": MethodRules(critic_on_prior=True, actor_rl_on_prior=True, uses_prior_memory=True),
    "ewc": MethodRules(ewc_penalty=True),
    "retain": MethodRules(merge=True),
    "single-task": MethodRules(inherit_actor=False, inherit_critic=False),
    "isolated": MethodRules(checkpoint_per_task=True),
}

# Table IV: each ablation changes one rule of ACCRUE
ABLATION_CHANGES: dict[str, dict] = {
    "none": {},
    "no-reference": {"use_reference": False},
    "beta0": {"zero_beta": True},
    "reset-critic": {"inherit_critic": False},
    "critic-all-replay": {"critic_on_prior": True},
}

METHODS = tuple(METHOD_RULES)
ABLATIONS = tuple(ABLATION_CHANGES)


def rules(method: str, ablation: str = "none") -> MethodRules:
    """The rules of `method` with `ablation` applied (ablations apply to ACCRUE only)."""
    base = METHOD_RULES[method]
    changes = ABLATION_CHANGES[ablation]
    if changes and method != "accrue":
        raise ValueError(f"ablation {ablation} applies to method 'accrue' only")
    return replace(base, **changes)
