"""Train the PPO policy shipped in ``agents/pretrained`` (same as ``safe-nav train``).

The shipped policy was made with exactly::

    python scripts/train_ppo.py --timesteps 400000 --seed 0 --n-envs 8 \
        --output agents/pretrained/ppo_random_crossing.zip
"""

from __future__ import annotations

import sys

from agents.cli import main

if __name__ == "__main__":
    sys.exit(main(["train", *sys.argv[1:]]))
