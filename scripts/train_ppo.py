"""Train a PPO reference planner (same as ``safe-nav train``; see ``--help``).

The shipped policy (``agents/pretrained/ppo_random_crossing.zip``) was made, on the
physical ±10 m/s² action box, with exactly::

    python scripts/train_ppo.py --timesteps 400000 --seed 0 --n-envs 8 --physical-actions \
        --env-option 'random_start={"probability": 0.5, "random_goal": 0.5}' \
        --output agents/pretrained/ppo_random_crossing.zip

Half the training episodes start at a random ego state (near the goal or anywhere in the
arena, at rest or moving), half of those with a random goal
(:class:`safe_nav_env.RandomStart`): the planner learns to reach its goal from the
states a safety filter leads it into. The reward is the environment's default (small
collision penalty): a goal-reaching planner, not a safe one. ``--physical-actions``
lets the learner act on the ±10 m/s² box (new runs act in [-1, 1] by default). The
variants of the safe-RL comparison, with the same recipe::

    # PPO-Lagrangian: cost = continuous-time collision indicator, limit 0 per episode
    python scripts/train_ppo.py --timesteps 400000 --seed 0 --n-envs 8 --physical-actions \
        --env-option 'random_start={"probability": 0.5, "random_goal": 0.5}' \
        --lagrangian --cost-limit 0.0 --lambda-lr 0.05 \
        --output runs/ppo_lagrangian.zip

    # PPO with the DR-CVaR filter in the loop (the wrapper's default reference)
    python scripts/train_ppo.py --timesteps 400000 --seed 0 --n-envs 8 --physical-actions \
        --env-option 'random_start={"probability": 0.5, "random_goal": 0.5}' \
        --filter dr_cvar --alpha 0.2 --delta 0.1 --epsilon 0.05 \
        --output runs/ppo_dr_cvar_in_loop.zip

(``agents/pretrained/ppo_lagrangian.zip`` and ``ppo_dr_cvar_in_loop.zip`` are these two
runs, with ``--output`` pointing there.) Each prints SB3's table with the ``safety/``
metrics after every rollout and writes ``<output>.metrics.csv``; ``--eval-freq N`` adds
held-out evaluations (``eval/``) and ``--tensorboard DIR`` TensorBoard event files.
"""

from __future__ import annotations

import sys

from agents.cli.main import main

if __name__ == "__main__":
    sys.exit(main(["train", *sys.argv[1:]]))
