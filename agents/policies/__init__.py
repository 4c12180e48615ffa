"""Trained PPO actors in the forms the filter and the evaluation use.

* :mod:`agents.policies.loading` — load a trained PPO policy (the shipped one or a file);
* :mod:`agents.policies.numpy_policy` — the actor exported to numpy, for the filter's
  roll-out reference;
* :mod:`agents.policies.go_to_goal` — an obstacle-blind go-to-goal controller (a reference
  whose collisions are the filter's alone).
"""
