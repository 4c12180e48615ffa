"""The stopping terminal set: invariance under its feedback, recursive feasibility of the QP."""

from __future__ import annotations

import numpy as np
import pytest

from filters.errors import InvalidParameterError
from filters.mpc import FilterStatus, stopping_terminal_set
from filters.mpc.terminal import stopping_input
from tests.builders import ARENA, TERMINAL, TS, A, B, C, T, make_filter, rollout

STOP = 0.5


def random_states_in_the_set(rng: np.random.Generator, count: int, G, g) -> np.ndarray:
    """Rejection sampling of states [p, v] with p in the arena and G x <= g."""
    out = []
    while len(out) < count:
        x = np.concatenate([rng.uniform(-ARENA, ARENA, 2), rng.uniform(-6.0, 6.0, 2)])
        if np.all(G @ x <= g) and np.all(np.abs(x[:2]) <= ARENA):
            out.append(x)
    return np.array(out)


def test_rows_are_the_documented_ones():
    G, g = stopping_terminal_set(TS, (-5.0, 4.0), (-5.0, 5.0), STOP)
    assert G.shape == (8, 4) and g.shape == (8,)
    a = 4.0 * (TS / 2 + STOP)  # min(|low|, high) = 4
    x = np.array([4.0, 0.0, 2.0, 0.0])  # p + c v = 5: on the face
    assert np.max(G @ x - g) == pytest.approx(0.0)
    assert np.all(G @ np.array([0.0, 0.0, a, -a]) <= g + 1e-12)
    assert np.any(G @ np.array([0.0, 0.0, a + 1e-6, 0.0]) > g)
    G_free, g_free = stopping_terminal_set(TS, None, (-np.inf, 5.0), STOP)
    assert G_free.shape == (2, 4) and np.all(np.isfinite(g_free))  # only p + c v <= high


@pytest.mark.parametrize("stop_time", [TS / 2, 0.3, 1.0])
def test_the_set_is_invariant_under_its_stopping_feedback(stop_time):
    rng = np.random.default_rng(0)
    G, g = stopping_terminal_set(TS, (-5.0, 5.0), (-ARENA, ARENA), stop_time)
    x = random_states_in_the_set(rng, 300, G, g)  # (300, 4), all at once
    reach = x[:, :2] + stop_time * x[:, 2:]
    for _ in range(5):
        u = stopping_input(x, TS, stop_time)
        assert np.all(np.abs(u) <= 5.0 + 1e-12)
        # inside the arena along the whole arc, not only at the samples
        for s in np.linspace(0.0, TS, 9):
            assert np.all(np.abs(x[:, :2] + s * x[:, 2:] + 0.5 * s**2 * u) <= ARENA + 1e-12)
        x = x @ A.T + u @ B.T
        assert np.all(x @ G.T <= g + 1e-12) and np.all(np.abs(x[:, :2]) <= ARENA + 1e-12)
        np.testing.assert_allclose(x[:, :2] + stop_time * x[:, 2:], reach, atol=1e-12)


def test_bad_arguments_raise():
    with pytest.raises(InvalidParameterError, match="stop_time"):
        stopping_terminal_set(TS, (-5.0, 5.0), (-5.0, 5.0), stop_time=0.05)
    with pytest.raises(InvalidParameterError, match="contain 0"):
        stopping_terminal_set(TS, (1.0, 5.0), (-5.0, 5.0))
    with pytest.raises(InvalidParameterError, match="dt"):
        stopping_terminal_set(0.0, (-5.0, 5.0), (-5.0, 5.0))


def test_a_shifted_feasible_plan_stays_feasible_without_obstacles():
    """Closed loop, random references running out of the arena: every step's hard QP is
    feasible, because the previous plan shifted and extended by the stopping input is."""
    rng = np.random.default_rng(1)
    mpc = make_filter(terminal_set=TERMINAL, n_obstacles=0)
    G, g = TERMINAL
    x = np.array([3.0, -2.0, 2.0, 1.0])
    plan = None
    for _ in range(40):
        target = rng.uniform(-9.0, 9.0, 2)  # often outside the arena
        reference = np.tile(np.concatenate([target, rng.uniform(-4, 4, 2)]), (T + 1, 1))
        if plan is not None:  # the candidate: shifted plan + stopping input, all rows hold
            states = rollout(x, plan[1:])
            candidate = np.vstack([plan[1:], stopping_input(states[-1], TS)])
            states = rollout(x, candidate)
            assert np.max(np.abs(states[1:] @ C.T)) <= ARENA + 1e-6
            assert np.max(G @ states[-1] - g) <= 1e-6 and np.max(np.abs(candidate)) <= 5.0 + 1e-6
        result = mpc.solve(x, reference, None)
        assert result.status is FilterStatus.OPTIMAL and mpc.last_qp_solves == 1
        plan = result.inputs
        x = A @ x + B @ result.first_input
