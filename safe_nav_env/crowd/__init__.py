"""Interactive crowds: CrowdNav's circle crossing with ORCA or social-force humans.

``gym.make("SafeNav/Crowd-v0", human_policy="orca", robot_visible=False)``; see
:class:`~safe_nav_env.crowd.env.CrowdEnv`.
"""

from safe_nav_env.crowd.env import CrowdEnv
from safe_nav_env.crowd.humans import HUMAN_POLICIES

__all__ = ["HUMAN_POLICIES", "CrowdEnv"]
