"""`python -m accrue.policy.lerobot_train_entry ARGS`: lerobot-train with accrue's policy types registered.

lerobot discovers third-party policies only from installed distributions named `lerobot_policy_*`; importing
accrue's policy package before lerobot parses its arguments registers `accrue_chunk_mlp` the same way.
"""

from accrue.policy.video_backend import use_pyav

use_pyav()  # before lerobot's configs are imported: its default decoder is pyav, no torchcodec probe

from lerobot.scripts.lerobot_train import main  # noqa: E402

import accrue.policy.chunk_mlp  # noqa: E402, F401 - registers the accrue_chunk_mlp config with lerobot

if __name__ == "__main__":
    main()
