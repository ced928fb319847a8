"""`python -m accrue.policy.lerobot_train_entry ARGS`: lerobot-train with accrue's policy types registered.

lerobot discovers third-party policies only from installed distributions named `lerobot_policy_*`; importing
accrue's policy package before lerobot parses its arguments registers `accrue_chunk_mlp` the same way.
"""

from lerobot.scripts.lerobot_train import main

import accrue.policy.chunk_mlp  # noqa: F401 - registers the accrue_chunk_mlp config with lerobot

if __name__ == "__main__":
    main()
