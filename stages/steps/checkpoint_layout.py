"""The layout of train's `checkpoint` output (and of each intra-step checkpoint), read by the steps
after it (handoff, evaluate): learner/, per_task/<i>/ (Isolated), checkpoint.json. Kept apart from
train.py so that handoff, which train imports, need not import train back."""

LEARNER_DIR, PER_TASK_DIR, CHECKPOINT_FILE = "learner", "per_task", "checkpoint.json"
