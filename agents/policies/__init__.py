"""Fast deterministic forms of a trained PPO actor, for the filter's roll-out reference.

* :mod:`agents.policies.numpy_policy` — the actor exported to numpy;
* :mod:`agents.policies.compiled_rollout` — the policy roll-out over the horizon in one
  compiled call;
* :mod:`agents.policies.vector_tanh` — the activation used by both.
"""
