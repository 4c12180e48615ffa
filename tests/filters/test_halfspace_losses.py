"""The sample losses -h.p of the halfspaces: linear work in T, the same bits as before.

Before, the losses were one batched product with the block-diagonal ``(T, T d)``
matrix of the normals (O(T^2) work per obstacle); now the products cover at most
16 steps each. Horizons up to 16 run the very same product; longer ones equal the
old product applied to each 16-step window, bit for bit.
"""

from __future__ import annotations

import numpy as np
import pytest

from filters import Disc, halfspaces, safe_halfspaces


def one_product_losses(points: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """The previous implementation: one block-diagonal product over all T steps."""
    n_obstacles, n_samples, horizon, dim = points.shape
    steps = np.arange(horizon)
    blocks = np.zeros((n_obstacles, horizon, horizon, dim))
    blocks[:, steps, steps, :] = normals
    flat = points.reshape(n_obstacles, n_samples, horizon * dim)
    return -(blocks.reshape(n_obstacles, horizon, horizon * dim) @ flat.transpose(0, 2, 1))


def instance(rng: np.random.Generator, n: int, n_samples: int, horizon: int, dim: int = 2):
    means = rng.uniform(-5.0, 5.0, (n, 1, horizon, dim))
    points = means + 0.1 * rng.standard_normal((n, n_samples, horizon, dim))
    reference = rng.uniform(-5.0, 5.0, (horizon, dim))
    return reference, points


@pytest.mark.parametrize("horizon", [1, 2, 10, 16])
@pytest.mark.parametrize("risk", ["mean", "cvar", "dr_cvar"])
def test_short_horizons_give_the_same_bits_as_one_product(horizon, risk, monkeypatch):
    rng = np.random.default_rng(horizon)
    for n, n_samples in ((1, 100), (3, 100), (20, 57)):
        reference, points = instance(rng, n, n_samples, horizon)
        kwargs = dict(ego_shape=Disc(0.3), obstacle_shapes=[Disc(0.3)] * n, risk=risk,
                      ego_velocity=np.array([1.5, 0.0]))
        new = safe_halfspaces(reference, points, **kwargs)
        with monkeypatch.context() as patch:
            patch.setattr(halfspaces, "_losses", one_product_losses)
            old = safe_halfspaces(reference, points, **kwargs)
        assert np.array_equal(new.offsets, old.offsets)
        assert np.array_equal(new.normals, old.normals)


@pytest.mark.parametrize("horizon", [17, 20, 33, 40, 80])
def test_long_horizons_are_the_one_product_losses_of_16_step_windows(horizon):
    rng = np.random.default_rng(horizon)
    for n, n_samples, dim in ((1, 100, 2), (5, 64, 2), (3, 31, 3)):
        _, points = instance(rng, n, n_samples, horizon, dim)
        normals = rng.standard_normal((n, horizon, dim))
        normals /= np.linalg.norm(normals, axis=-1, keepdims=True)
        losses = halfspaces._losses(points, normals)
        assert losses.shape == (n, horizon, n_samples) and losses.flags.c_contiguous
        windows = [one_product_losses(np.ascontiguousarray(points[:, :, s : s + 16]),
                                      normals[:, s : s + 16]) for s in range(0, horizon, 16)]
        assert np.array_equal(losses, np.concatenate(windows, axis=1))
        # and the one product over all steps agrees to rounding (it differs from itself
        # by the BLAS tiling, hence the last bit of a few entries)
        exact = -np.einsum("isTd,iTd->iTs", points, normals)
        scale = np.max(np.abs(exact))
        assert np.max(np.abs(losses - exact)) <= 4e-16 * scale
        assert np.max(np.abs(one_product_losses(points, normals) - losses)) <= 4e-16 * scale


def test_long_horizon_halfspaces_equal_those_of_their_windows():
    """Each step's halfspace depends on that step's data only, and so do its bits."""
    rng = np.random.default_rng(7)
    reference, points = instance(rng, 20, 500, 40)
    shapes = [Disc(0.3)] * 20
    whole = safe_halfspaces(reference, points, ego_shape=Disc(0.3), obstacle_shapes=shapes)
    for start in (0, 16, 32):
        window = safe_halfspaces(reference[start : start + 16], points[:, :, start : start + 16],
                                 ego_shape=Disc(0.3), obstacle_shapes=shapes)
        assert np.array_equal(whole.offsets[:, start : start + 16], window.offsets)
        assert np.array_equal(whole.normals[:, start : start + 16], window.normals)
