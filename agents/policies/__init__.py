"""The fast deterministic form of a trained PPO actor: :mod:`agents.policies.numpy_policy`
(the actor exported to numpy, for the filter's roll-out reference)."""
