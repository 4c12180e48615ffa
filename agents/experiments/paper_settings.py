"""The paper's settings for ``safe-nav reproduce``: its numbers, scenarios and presets.

The paper's reported values (worst distances, filter time, the statistics windows of
its box plots), the two settings compared with it (:data:`PRESETS`: the paper's text
and the authors' code) and the paper's episode length of a scenario
(:func:`paper_duration`). Used by :mod:`agents.experiments.reproduce`.
"""

from __future__ import annotations

from dataclasses import dataclass

from agents.evaluation.records import PAPER_SCENARIOS as PAPER_SCENARIO_NAMES
from agents.planners import AUTHORS_CODE_PLANNER
from filters.constants import ALPHA, DELTA, EPSILON, HORIZON
from filters.errors import InvalidParameterError
from safe_nav_env.scenarios import env_id

PAPER_SCENARIOS = tuple(env_id(name) for name in PAPER_SCENARIO_NAMES)
"""The paper's four scenarios by gym id (reproduce's encounters are keyed by gym id)."""

PAPER_WORST_DISTANCE = {"mean": -0.45, "cvar": -0.22}
"""Section IV-B: worst sampled distance to collision in the box plots (300 runs, the
three single-obstacle scenarios, on :data:`PAPER_WINDOWS`); DR-CVaR: no collision."""

PAPER_FILTER_TIME_MS = 7.0
"""Section IV-B: mean filter call time in the multi-obstacle run (CVXPY + ECOS)."""

PAPER_WINDOWS: dict[str, tuple[int, int]] = {
    "SafeNav/HeadOn-v0": (5, 8),
    "SafeNav/Overtaking-v0": (2, 5),
    "SafeNav/Intersection-v0": (5, 8),
}
"""The samples of the authors' box plots, ``(first, last)`` both included; sample 0 is
the initial state, sample k the state after k steps of 0.2 s. From the authors'
``multi_exp_sim.py``: ``start=6, end=9`` (HeadOn, Intersection) and ``start=3,
end=6`` (Overtaking), sliced as ``[start - 1 : end]``."""

TOLERANCE_M = 0.1
"""A worst distance "matches" the paper's when within 0.1 m of it."""


# ---------------------------------------------------------------------------- presets
@dataclass(frozen=True)
class ReproductionPreset:
    """Settings of one paper-comparison Monte Carlo.

    Both presets give the filter the input cost ``u' R u`` of Problem 2 (the paper's and
    the authors' code's; :mod:`agents.experiments.encounters`), not the package's
    default ``(u - u_ref)' R (u - u_ref)``.

    Attributes
    ----------
    name, description
        Identifier and one line for the report.
    noise
        Environment noise preset (:data:`safe_nav_env.NOISE_PRESETS`).
    planner_convention, planner_weights
        Convention (:data:`agents.planners.CONVENTIONS`) and ``(Q, Q_T, R)`` of the
        obstacle-agnostic reference planner, read in that convention.
    filter_weights
        ``(Q, Q_T, R)`` of the safety filter, effective (``x' Q x``), times identity.
    max_acceleration
        Input bound per axis of the environment, the planner and the filter, in m/s².
    alpha, delta, epsilon
        Tail mass, risk bound (m) and Wasserstein radius (m).
    mean_delta
        δ of the mean halfspace, in m (``None``: ``delta``).
    horizon
        Planner and filter horizon, in steps.
    fallback
        The filter's rule when its QP is infeasible (:data:`filters.mpc.filter.FALLBACKS`):
        ``"paper"`` shifts the last plan (the paper's Remark, the authors' code).
    """

    name: str
    description: str
    noise: str
    planner_convention: str
    planner_weights: tuple[float, float, float]
    filter_weights: tuple[float, float, float]
    max_acceleration: float
    alpha: float = ALPHA
    delta: float = DELTA
    epsilon: float = EPSILON
    mean_delta: float | None = None
    horizon: int = HORIZON
    fallback: str = "paper"

    def delta_for(self, risk: str) -> float:
        """δ used with ``risk``, in m."""
        return float(self.mean_delta if risk == "mean" and self.mean_delta is not None
                     else self.delta)


PRESETS: dict[str, ReproductionPreset] = {
    "paper": ReproductionPreset(
        name="paper",
        description="the paper's text: 100 samples of N(0, 0.01 I), Laplace reality with the "
                    "same covariance; our planner convention (x'Qx: Q 1, Q_T 3, R 1 on every "
                    "input, arena bound); filter 4 I, 25 I, I with the input cost u'Ru of "
                    "Problem 2 and the paper's fallback (shift the last plan); |u| <= 10 m/s²; "
                    "δ = 0.1 m for every metric",
        noise="paper", planner_convention="quadratic", planner_weights=(1.0, 3.0, 1.0),
        filter_weights=(4.0, 25.0, 1.0), max_acceleration=10.0,
    ),
    "authors_code": ReproductionPreset(
        name="authors_code",
        description="the authors' code: 20 samples of N(0, 0.1 I), Laplace reality of scale "
                    "0.1 m; their planner sum_squares((x-g) Q) with Q 1, Q_T 3, R 1 on "
                    "u_1..u_9 (effective 1, 9, 1; u_0 free; no arena bound); filter "
                    "sum_squares((x-x_ref) Q) + sum_squares(u R) with Q 2, Q_T 5, R 1 "
                    "(effective 4, 25, 1) and the shifted-plan fallback; |u| <= 100 m/s²; the "
                    "mean halfspace with δ = 0",
        noise="authors_code", planner_convention="authors_code",
        planner_weights=(AUTHORS_CODE_PLANNER["Q"], AUTHORS_CODE_PLANNER["Q_terminal"],
                         AUTHORS_CODE_PLANNER["R"]),
        filter_weights=(2.0**2, 5.0**2, 1.0**2),  # sum_squares(e * q) = q² e'e: Q 2, Q_T 5, R 1
        max_acceleration=AUTHORS_CODE_PLANNER["max_acceleration"], mean_delta=0.0,
        horizon=int(AUTHORS_CODE_PLANNER["horizon"]),
    ),
}
"""The two settings :func:`reproduce` compares with the paper."""


def paper_duration(scenario: str) -> float:
    """The paper's episode length of a registered scenario id (its ``duration``), in s.

    Raises
    ------
    InvalidParameterError
        If ``scenario`` is not a registered id with a fixed scenario.
    """
    from safe_nav_env import ENV_IDS, SCENARIOS, Scenario

    name = ENV_IDS.get(scenario)
    value = SCENARIOS.get(name) if name is not None else None
    if not isinstance(value, Scenario):
        fixed = sorted(k for k, v in ENV_IDS.items() if isinstance(SCENARIOS.get(v), Scenario))
        raise InvalidParameterError(
            f"scenario must be a registered id with a fixed scenario {fixed}, got {scenario!r}")
    return float(value.duration)
