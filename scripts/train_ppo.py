"""Train a PPO reference planner (same as ``safe-nav train``; see ``--help``).

The shipped policy (``agents/pretrained``) was made, on the physical ±10 m/s²
action box, with exactly::

    python scripts/train_ppo.py --timesteps 400000 --seed 0 --n-envs 8 \
        --output agents/pretrained/ppo_random_crossing.zip

(add ``--physical-actions`` to repeat that now: new runs let the learner act in
[-1, 1] by default). The variants of the safe-RL comparison::

    # PPO-Lagrangian: cost = continuous-time collision indicator, limit 0 per episode
    python scripts/train_ppo.py --timesteps 400000 --seed 0 --n-envs 8 \
        --lagrangian --cost-limit 0.0 --lambda-lr 0.05 \
        --output runs/ppo_lagrangian.zip

    # PPO with the DR-CVaR filter in the loop (the wrapper's default reference)
    python scripts/train_ppo.py --timesteps 400000 --seed 0 --n-envs 8 \
        --filter dr_cvar --alpha 0.2 --delta 0.1 --epsilon 0.05 \
        --output runs/ppo_dr_cvar_in_loop.zip

Each prints SB3's table with the ``safety/`` metrics after every rollout and writes
``<output>.metrics.csv``; ``--eval-freq N`` adds held-out evaluations (``eval/``) and
``--tensorboard DIR`` TensorBoard event files.
"""

from __future__ import annotations

import sys

from agents.cli import main

if __name__ == "__main__":
    sys.exit(main(["train", *sys.argv[1:]]))
