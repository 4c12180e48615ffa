"""The compiled roll-out's arithmetic against plain numpy: ``tanh`` to 2 ulp, and the
layer sums and sample means bit for bit (the same additions in the same order)."""

from __future__ import annotations

import numpy as np
import pytest

from agents.policies.compiled_rollout import _affine, _sample_means
from agents.policies.vector_tanh import tanh_array


def _points() -> np.ndarray:
    rng = np.random.default_rng(12)
    return np.concatenate([
        np.linspace(-20.0, 20.0, 2_000_001),  # dense grid, step 2e-5
        rng.uniform(-20.0, 20.0, 200_000),
        3.0 * rng.standard_normal(200_000),  # where a network's pre-activations sit
        np.geomspace(1e-300, 20.0, 20_000),  # tiny values: tanh x = x
        -np.geomspace(1e-300, 20.0, 20_000),
        np.nextafter(0.625, [-1.0, 2.0]), [0.625, -0.625, 19.0, 19.1, 25.0, 1e300, 5e-324],
    ])


def test_tanh_is_within_two_ulp_of_numpy():
    x = _points()
    mine = np.empty_like(x)
    tanh_array(x, mine)
    exact = np.tanh(x)
    error = np.abs(mine - exact)
    assert error.max() <= 2.3e-16  # the bound the module docstring states
    assert np.all(error <= 2 * np.spacing(np.abs(exact)))  # 2 units in the last place
    assert np.mean(mine == exact) > 0.7  # mostly the very same bits
    assert np.all(np.abs(mine) <= 1.0)


def test_tanh_is_odd_and_handles_special_values():
    x = _points()
    plus, minus = np.empty_like(x), np.empty_like(x)
    tanh_array(x, plus)
    tanh_array(-x, minus)
    assert np.array_equal(plus, -minus)
    special = np.array([0.0, -0.0, np.inf, -np.inf, np.nan])
    out = np.empty_like(special)
    tanh_array(special, out)
    assert np.array_equal(out[:4], [0.0, 0.0, 1.0, -1.0])
    assert list(np.signbit(out[:2])) == [False, True]
    assert np.isnan(out[4])


@pytest.mark.parametrize("n_in, n_out", [(26, 64), (64, 64), (64, 2), (7, 9), (3, 8), (5, 1)])
def test_affine_sums_in_input_order(n_in, n_out):
    rng = np.random.default_rng(n_in * 100 + n_out)
    for _ in range(20):
        src = np.concatenate([rng.standard_normal(n_in) * 10.0 ** rng.uniform(-8, 3), [9.0]])
        weight = rng.standard_normal((n_in, n_out)) * 10.0 ** rng.uniform(-3, 3)
        dst = np.full(n_out + 3, 7.0)
        _affine(src, weight, dst)
        # cumsum adds in order: ((z_0 w_0 + z_1 w_1) + z_2 w_2) + ...
        expected = np.cumsum(src[:n_in, None] * weight, axis=0)[-1]
        assert np.array_equal(dst[:n_out], expected)
        assert np.all(dst[n_out:] == 7.0)  # nothing past the outputs is touched


@pytest.mark.parametrize("shape, steps", [((3, 100, 10, 2), 9), ((1, 7, 4, 2), 3),
                                          ((4, 50, 20, 2), 5), ((2, 3, 5, 2), 0)])
def test_sample_means_add_the_samples_in_order(shape, steps):
    rng = np.random.default_rng(shape[1])
    predictions = rng.standard_normal(shape) * 10.0 + rng.uniform(-50, 50, (shape[0], 1, 1, 2))
    means = np.full((shape[0], steps, 2), np.nan)
    _sample_means(predictions, means)
    expected = np.cumsum(predictions, axis=1)[:, -1, :steps] / shape[1]
    assert np.array_equal(means, expected)
