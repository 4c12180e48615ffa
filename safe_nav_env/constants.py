r"""The environment's numbers, each defined once (Safaoui & Summers, ICRA 2024, Sec. IV).

The ego is a double integrator sampled every :data:`DT` seconds; ego and obstacles are
discs; positions live in the square arena :data:`ARENA`. The filter's own defaults
(:math:`\alpha`, :math:`\delta`, :math:`\epsilon`, its horizon) are in
:mod:`filters.constants`.
"""

DT = 0.2
"""Sampling time :math:`T_s` in s."""
HORIZON = 10
"""Prediction horizon in steps: ``info["predictions"]`` covers steps t+1..t+HORIZON."""
N_SAMPLES = 100
"""Prediction samples per obstacle and step, :math:`N_s`."""
NOISE_VARIANCE = 0.01
"""Per-axis variance of the paper's obstacle noise, m² (std 0.1 m): the prediction law
``N(0, 0.01 I)`` and the realised Laplace law with the same covariance."""
EGO_RADIUS = 0.3
"""Radius of the ego disc :math:`r_A` in m."""
OBSTACLE_RADIUS = 0.3
"""Radius of an obstacle disc :math:`r_O` in m."""
ARENA_HALF_WIDTH = 5.0
"""Half width in m of the square arena centred on the origin."""
ARENA = ((-ARENA_HALF_WIDTH, -ARENA_HALF_WIDTH), (ARENA_HALF_WIDTH, ARENA_HALF_WIDTH))
"""The arena ``((x_min, y_min), (x_max, y_max))`` in m: :math:`[-5, 5]^2`."""
MAX_ACCELERATION = 10.0
"""Input bound in m/s² per axis: the action space is ``[-10, 10]²``."""
EGO_START_SPEED = 1.5
"""Speed in m/s along +x at which the ego starts in the paper's scenarios."""
MAX_SPEED = 5.0
r"""Speed limit :math:`v_\max` of the ego in m/s: the environment keeps
:math:`\|v\|_2 \le v_\max`. Chosen by measurement on the paper's scenes (at 3 m/s the
filtered MPC planner collided head-on; see CHANGELOG.md)."""
PAPER_SCENARIOS = ("HeadOn", "Overtaking", "Intersection", "MultiObstacle")
"""The paper's four scenarios (gym ids ``SafeNav/<name>-v0``)."""
