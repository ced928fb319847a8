"""The ACCRUE learner: chunked off-policy actor-critic with a categorical critic (paper Sec. III-C, IV).

Plain torch modules and functions; knows nothing of the store or the CLI. Where each equation lives:
    Eq. 1  losses.actor_loss_current        Eq. 2  losses.td_target + distributional.project_target
    Eq. 3  continual.compute_teacher_targets Eq. 4  losses.distill_loss_prior
    Eq. 5  losses.actor_loss_total          Algorithm 1  accrue.stage_rl (top to bottom) + agent.update
Each continual method's rules: accrue.methods (one table row per method and ablation).
"""

from accrue.learner.agent import ChunkLearner
from accrue.learner.config import ABLATIONS, ALGOS, METHODS, LearnerConfig
from accrue.learner.continual import (
    begin_stage,
    compute_teacher_targets,
    copy_learner,
    end_stage,
    estimate_fisher,
    make_learner,
)
from accrue.learner.replay import Batch, ReplayBuffer, retain_last_episodes
from accrue.learner.state import load_learner, save_learner, training_state

__all__ = [
    "ABLATIONS",
    "ALGOS",
    "METHODS",
    "Batch",
    "ChunkLearner",
    "LearnerConfig",
    "ReplayBuffer",
    "begin_stage",
    "compute_teacher_targets",
    "copy_learner",
    "end_stage",
    "estimate_fisher",
    "load_learner",
    "make_learner",
    "retain_last_episodes",
    "save_learner",
    "training_state",
]
