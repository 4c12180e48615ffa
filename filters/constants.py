r"""The filter's numbers, each defined once: the paper's defaults and the QP's tolerances.

Defaults of Safaoui & Summers (ICRA 2024), Table I and Section IV. :math:`\alpha` is the
CVaR tail mass (:math:`\alpha = 1` gives the mean), :math:`\delta` the loss bound (m) of
each safe halfspace, :math:`\epsilon` the Wasserstein radius (m) of DR-CVaR's ambiguity
set, ``HORIZON`` the MPC horizon :math:`T` in steps. The environment's own constants
(sampling time, radii, arena) live in :mod:`safe_nav_env.constants`: ``filters`` knows
nothing of ``safe_nav_env``.
"""

ALPHA = 0.2
"""CVaR tail mass :math:`\alpha` (also the chance constraints' allowed probability)."""
DELTA = 0.1
r"""Loss bound :math:`\delta` in m: a halfspace keeps :math:`R(\ell) \le \delta`."""
EPSILON = 0.05
r"""Wasserstein radius :math:`\epsilon` in m of DR-CVaR's ambiguity set."""
HORIZON = 10
"""MPC horizon :math:`T` in steps (2 s at the paper's :math:`T_s = 0.2` s)."""
SPEED_SIDES = 8
r"""Sides :math:`M` of the polygon inscribed in the speed disc :math:`\|v\| \le v_\max`
that the MPC keeps (its rows :math:`h_j^\top v \le v_\max \cos(\pi/M)`)."""

DISABLED_OFFSET = 1.0
"""Offset written in unused halfspace rows: the row reads ``0 @ y <= 1``."""
FEASIBILITY_TOLERANCE = 1e-6
"""Largest violation (m for positions and halfspaces) accepted from a "solved" QP."""
SLACK_TOLERANCE = 1e-6
"""Slacks and violations at or below this value (m) count as zero."""
INPUT_CLIP_TOLERANCE = 1e-4
"""Largest distance (m/s², per input) from a back end's answer to the input box that is
clipped away rather than rejected. Every row is checked again on the clipped inputs, so
clipping never admits a plan that breaks a hard row. Active-set soft QPs in the whitened
variables (where the box is a general row) were seen up to 2e-5 outside it."""
