"""Shared builders of the MPC tests: the paper's double integrator and random instances."""

from __future__ import annotations

from typing import Any

import numpy as np

from benchmarks.filter_qp import double_integrator, filter_kwargs
from filters.mpc import MPCSafetyFilter, stopping_terminal_set

T = 10
TS = 0.2
A, B, C = double_integrator(TS)
KWARGS = filter_kwargs(T, 3)  # Q = 4 I, Q_T = 25 I, R = I, |u| <= 5, arena [-5, 5]^2
ARENA = 5.0
INPUT_LIMIT = 5.0
TERMINAL = stopping_terminal_set(TS, KWARGS["input_bounds"], KWARGS["position_bounds"])


def make_filter(backend: str = "clarabel", **change: Any) -> MPCSafetyFilter:
    """A filter of the paper's size; ``change`` overrides constructor keywords."""
    kwargs = {**KWARGS, **change}
    if kwargs.get("objective") == "first_input":
        kwargs.pop("Q", None)
        kwargs.pop("Q_terminal", None)
    if backend == "cvxpy":
        kwargs.setdefault("skip_feasible_reference", False)
    return MPCSafetyFilter(A, B, C, backend=backend, **kwargs)


def rollout(x0: np.ndarray, inputs: np.ndarray) -> np.ndarray:
    """States ``(T + 1, n)`` of the double integrator under ``inputs``."""
    states = [np.asarray(x0, dtype=float)]
    for u in inputs:
        states.append(A @ states[-1] + B @ u)
    return np.array(states)


def random_instance(
    rng: np.random.Generator, k: int, *, with_inputs: bool = False
) -> dict[str, Any]:
    """Ego at 1.5 m/s along +x, ``k`` obstacles ahead, halfspaces toward them."""
    x0 = np.array([rng.uniform(-4.0, 0.0), rng.uniform(-1.0, 1.0), 1.5, rng.normal(0, 0.2)])
    reference = np.empty((T + 1, 4))
    reference[:, 0] = x0[0] + 1.5 * TS * np.arange(T + 1)
    reference[:, 1] = x0[1] + rng.normal(0, 0.2)
    reference[:, 2:] = (1.5, 0.0)
    obstacles = x0[:2] + np.column_stack([rng.uniform(1.0, 4.0, k), rng.uniform(-1.0, 1.0, k)])
    velocity = rng.normal(0.0, 0.4, (k, 2))
    predicted = obstacles[:, None] + velocity[:, None] * TS * np.arange(1, T + 1)[None, :, None]
    direction = predicted - reference[None, 1:, :2]
    normals = direction / np.linalg.norm(direction, axis=-1, keepdims=True)
    offsets = np.einsum("ktd,ktd->kt", normals, predicted) - rng.uniform(0.5, 0.8, (k, 1))
    instance: dict[str, Any] = {
        "x0": x0, "reference_states": reference, "halfspaces": (normals, offsets)
    }
    if with_inputs:
        instance["reference_inputs"] = rng.normal(0.0, 1.0, (T, 2))
    return instance


def consistent_reference(rng: np.random.Generator, k: int, margin: float):
    """Inputs, the states they generate, and halfspaces the states keep ``margin`` from."""
    x0 = np.array([rng.uniform(-2, 0), rng.uniform(-1, 1), rng.uniform(-1, 1), rng.uniform(-1, 1)])
    inputs = rng.uniform(-1.0, 1.0, (T, 2))
    states = rollout(x0, inputs)
    normals = rng.normal(size=(k, T, 2))
    normals /= np.linalg.norm(normals, axis=-1, keepdims=True)
    offsets = np.einsum("ktd,td->kt", normals, states[1:, :2]) + margin
    return x0, inputs, states, (normals, offsets)


def solve(mpc: MPCSafetyFilter, instance: dict[str, Any]):
    """``mpc.solve`` on an instance dict."""
    return mpc.solve(
        instance["x0"], instance["reference_states"], instance["halfspaces"],
        reference_inputs=instance.get("reference_inputs"),
    )


def infeasible_halfspaces(k: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """x <= -100 m at every step: unreachable."""
    normals = np.zeros((k, T, 2))
    normals[..., 0] = 1.0
    return normals, np.full((k, T), -100.0)


def halfspace_violation(states: np.ndarray, halfspaces) -> np.ndarray:
    """``a @ C x_t - b`` of every row, ``(k, T)``."""
    normals, offsets = halfspaces
    return np.einsum("ktd,td->kt", normals, states[1:] @ C.T) - offsets


def hard_violation(result, halfspaces, *, terminal: bool = False) -> float:
    """Largest violation of any halfspace, arena, input or terminal row by ``result``."""
    positions = result.states[1:] @ C.T
    worst = [
        float(np.max(halfspace_violation(result.states, halfspaces), initial=-np.inf)),
        float(np.max(np.abs(positions)) - ARENA),
        float(np.max(np.abs(result.inputs)) - INPUT_LIMIT),
    ]
    if terminal:
        G, g = TERMINAL
        worst.append(float(np.max(G @ result.states[-1] - g)))
    return max(worst)
