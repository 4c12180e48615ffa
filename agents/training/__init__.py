"""Training reference planners: PPO (Stable-Baselines3), optionally with the filter in the loop.

* :mod:`agents.training.ppo` — :func:`~agents.training.ppo.train_ppo`,
  :func:`~agents.training.ppo.load_ppo`;
* :mod:`agents.training.wrappers` — the learner's view of the environment (episode cost,
  normalised actions);
* :mod:`agents.training.callbacks` — safety metrics per roll-out (SB3 callbacks);
* :mod:`agents.training.lagrangian` — PPO-Lagrangian, the constrained-RL baseline.

torch and Stable-Baselines3 are imported only by the modules that need them.
"""
