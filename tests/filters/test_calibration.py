"""Online calibration: the prediction record, conformal margins and Wasserstein radii."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import stats
from scipy.special import ndtr, ndtri

from filters.calibration import (
    ConformalMargin,
    OnlineCalibration,
    PredictionRecord,
    WassersteinRadius,
    conformal_rank,
    sliced_wasserstein_max,
)
from filters.errors import InvalidArrayError, InvalidParameterError
from filters.wasserstein import grid_directions


def clopper_pearson(successes: int, trials: int, confidence: float = 0.99) -> tuple[float, float]:
    """Exact two-sided binomial confidence interval for a proportion."""
    tail = (1.0 - confidence) / 2.0
    low = 0.0 if successes == 0 else stats.beta.ppf(tail, successes, trials - successes + 1)
    high = 1.0 if successes == trials else stats.beta.ppf(1 - tail, successes + 1,
                                                          trials - successes)
    return float(low), float(high)


# --------------------------------------------------------------------------- record


def test_record_matches_each_realised_position_with_the_prediction_issued_k_steps_before():
    # Obstacles on straight lines; the samples of step t+k are the true position plus
    # symmetric offsets (mean exactly the truth), so every error is 0 and the
    # predicted errors are the offsets.
    horizon, n_obs = 4, 2
    velocity = np.array([[1.0, 0.5], [-0.3, 0.2]])
    offsets = np.array([[0.1, 0.0], [-0.1, 0.0], [0.0, 0.2], [0.0, -0.2]])  # mean 0
    record = PredictionRecord(horizon=horizon, keep_samples=3)
    for t in range(8):
        future = velocity[:, None, :] * (t + np.arange(1, horizon + 2))[None, :, None]
        samples = future[:, None, :, :] + offsets[None, :, None, :]  # (2, 4, T + 1, 2)
        realised = record.update(samples, velocity * t)
        assert [r.lookahead for r in realised] == list(range(1, min(t, horizon) + 1))
        for r in realised:
            assert r.step == t and r.n_samples == 4
            assert r.errors.shape == (n_obs, 2) and r.scores.shape == (n_obs,)
            np.testing.assert_allclose(r.errors, 0.0, atol=1e-12)
            np.testing.assert_allclose(r.predicted_errors, np.broadcast_to(offsets[:3], (2, 3, 2)),
                                       atol=1e-12)
            assert not r.errors.flags.writeable
    assert record.scores(1).shape == (7 * n_obs,)
    assert record.scores(4).shape == (4 * n_obs,)


def test_record_errors_are_realised_minus_sample_mean():
    rng = np.random.default_rng(0)
    record = PredictionRecord(horizon=3)
    first = rng.normal(size=(2, 5, 3, 2))
    record.update(first, rng.normal(size=(2, 2)))
    second = rng.normal(size=(2, 5, 3, 2))
    record.update(second, rng.normal(size=(2, 2)))
    positions = rng.normal(size=(2, 2))
    realised = record.update(rng.normal(size=(2, 5, 3, 2)), positions)
    k1, k2 = realised
    np.testing.assert_allclose(k1.errors, positions - second[:, :, 0].mean(axis=1))
    np.testing.assert_allclose(k2.errors, positions - first[:, :, 1].mean(axis=1))
    np.testing.assert_allclose(k2.scores, np.linalg.norm(k2.errors, axis=1))


def test_record_reset_forgets_pending_predictions_and_rejects_silent_shape_changes():
    record = PredictionRecord(horizon=2)
    record.update(np.zeros((3, 4, 2, 2)), np.zeros((3, 2)))
    with pytest.raises(InvalidArrayError, match="reset"):
        record.update(np.zeros((2, 4, 2, 2)), np.zeros((2, 2)))
    record.reset()
    assert record.update(np.zeros((2, 4, 2, 2)), np.zeros((2, 2))) == ()
    with pytest.raises(InvalidArrayError, match="realised_positions"):
        record.update(np.zeros((2, 4, 2, 2)), np.zeros((3, 2)))
    with pytest.raises(InvalidArrayError, match="samples"):
        record.update(np.full((2, 4, 2, 2), np.nan), np.zeros((2, 2)))
    with pytest.raises(InvalidParameterError, match="horizon"):
        PredictionRecord(horizon=0)


def test_record_with_ids_scores_each_prediction_against_its_own_obstacle():
    # Three obstacles a, b, c (ids 10, 11, 12) at fixed, far apart points, every
    # prediction exact. Two slots: a leaves slot 0 to c at step 1, and comes back in
    # slot 1 at step 2 (where b was). Paired by id every score is 0; paired by slot
    # the swaps would score the distance between two obstacles.
    where = {10: np.array([0.0, 0.0]), 11: np.array([10.0, 0.0]), 12: np.array([0.0, 10.0])}
    slots = [[10, 11], [12, 11], [12, 10], [-1, 10]]

    def exact(ids: list[int]) -> tuple[np.ndarray, np.ndarray]:
        positions = np.array([where.get(i, np.array([99.0, 99.0])) for i in ids])
        return np.broadcast_to(positions[:, None, None, :], (2, 3, 3, 2)).copy(), positions

    record = PredictionRecord(horizon=3)
    scored = []
    for ids in slots:
        samples, positions = exact(ids)
        for r in record.update(samples, positions, ids=np.array(ids)):
            np.testing.assert_allclose(r.scores, 0.0, atol=1e-12)
            scored.append((r.step, r.lookahead, r.ids.tolist()))
    # Step 1: only b (11) was predicted at step 0 and is still there. Step 2: a (10)
    # is back, in b's old slot, and meets its own step-0 prediction; c (12) its step-1
    # one. Step 3: the empty slot (-1) is neither scored nor stored; a meets its step-2
    # and step-0 predictions, and nobody of step 1 is left.
    assert scored == [(1, 1, [11]), (2, 1, [12]), (2, 2, [10]), (3, 1, [10]), (3, 3, [10])]

    # Paired by slot (no ids), the same stream scores the swaps.
    by_slot = PredictionRecord(horizon=3)
    worst = 0.0
    for ids in slots:
        samples, positions = exact(ids)
        for r in by_slot.update(samples, positions):
            worst = max(worst, float(r.scores.max()))
    assert worst >= 10.0


def test_record_ids_are_validated():
    record = PredictionRecord(horizon=2)
    with pytest.raises(InvalidArrayError, match="distinct"):
        record.update(np.zeros((2, 3, 2, 2)), np.zeros((2, 2)), ids=np.array([4, 4]))
    with pytest.raises(InvalidArrayError, match="ids must be 2 integers"):
        record.update(np.zeros((2, 3, 2, 2)), np.zeros((2, 2)), ids=np.array([0.5, 1.0]))
    with pytest.raises(InvalidArrayError, match="ids must be 2 integers"):
        record.update(np.zeros((2, 3, 2, 2)), np.zeros((2, 2)), ids=np.array([1, 2, 3]))
    # With ids the row count may change between steps (rows are matched by id).
    record.update(np.zeros((2, 3, 2, 2)), np.zeros((2, 2)), ids=np.array([-1, 7]))
    (k1,) = record.update(np.ones((3, 3, 2, 2)), np.zeros((3, 2)), ids=np.array([3, 7, 9]))
    assert k1.ids.tolist() == [7] and k1.errors.shape == (1, 2)
    # Every row empty at both steps: nothing to score, no empty realisation.
    empty = PredictionRecord(horizon=2)
    for _ in range(3):
        assert empty.update(np.zeros((2, 3, 2, 2)), np.zeros((2, 2)), ids=[-1, -1]) == ()


# --------------------------------------------------------------------------- conformal


def test_conformal_rank():
    assert conformal_rank(19, 0.1) == 18  # (19 + 1) * 0.9 = 18 exactly
    assert conformal_rank(9, 0.1) == 9
    assert conformal_rank(8, 0.1) == 9  # > n: no finite margin yet
    assert conformal_rank(100, 1.0) == 0
    assert conformal_rank(100, 0.2) == 81


@pytest.mark.parametrize("law", ["exponential", "lognormal"])
def test_split_conformal_coverage_is_inside_the_binomial_interval(law):
    # Independent trials: n calibration scores, then one test score, from a known law.
    # For a continuous law the coverage is exactly rank / (n + 1).
    rng = np.random.default_rng(1)
    alpha, n, trials = 0.1, 24, 3000
    draw = (lambda size: rng.exponential(size=size)) if law == "exponential" else (
        lambda size: rng.lognormal(sigma=1.5, size=size))
    covered = 0
    for _ in range(trials):
        margin = ConformalMargin(alpha, horizon=1, window=n, gamma=0.0)
        margin.update_scores(1, draw(n))
        covered += int(draw(1)[0] <= margin.margin(1))
    expected = conformal_rank(n, alpha) / (n + 1)
    low, high = clopper_pearson(covered, trials)
    assert expected >= 1 - alpha
    assert low <= expected <= high


def test_sliding_window_margin_is_the_rank_statistic_of_the_last_window_scores():
    rng = np.random.default_rng(2)
    margin = ConformalMargin(0.2, horizon=2, window=10, gamma=0.0)
    scores = rng.exponential(size=37)
    for s in scores:
        margin.update_scores(2, [s])
    window = np.sort(scores[-10:])
    assert margin.margin(2) == window[conformal_rank(10, 0.2) - 1]


def test_aci_long_run_miscoverage_meets_the_gibbs_candes_bound_under_a_shift():
    rng = np.random.default_rng(3)
    alpha, gamma, steps = 0.1, 0.01, 6000
    margin = ConformalMargin(alpha, horizon=1, window=100, gamma=gamma)  # fallback inf
    plain = ConformalMargin(alpha, horizon=1, window=100, gamma=0.0)
    errors, plain_errors = [], []
    for t in range(steps):
        scale = 1.0 if t < steps // 3 else (4.0 if t < 2 * steps // 3 else 0.5)
        score = scale * abs(rng.standard_t(3))
        errors.append(margin.update_scores(1, [score]))
        plain_errors.append(plain.update_scores(1, [score]))
    bound = (max(alpha, 1 - alpha) + gamma) / (gamma * steps)
    assert abs(np.mean(errors) - alpha) <= bound
    assert margin.coverage()[0] == pytest.approx(1 - np.mean(errors))
    assert -gamma <= margin.levels[0] <= 1 + gamma


def test_conformal_fallbacks_before_enough_scores():
    assert ConformalMargin(0.1, horizon=3).margins().tolist() == [math.inf] * 3
    assert ConformalMargin(0.1, horizon=3, fallback=0.7).margins().tolist() == [0.7] * 3
    margin = ConformalMargin(0.1, horizon=2, fallback="max", gamma=0.0)
    assert margin.margin(1) == math.inf
    margin.update_scores(1, [0.2, 0.5, 0.3])  # 3 scores: rank 4 > 3 -> the largest seen
    assert margin.margin(1) == 0.5
    margin.update_scores(1, np.linspace(0.0, 0.1, 10))  # 13 scores: rank 13 -> the 13th
    assert margin.margin(1) == 0.5
    for bad in (0.0, 1.0, -0.1):
        with pytest.raises(InvalidParameterError, match="alpha"):
            ConformalMargin(bad, horizon=2)
    with pytest.raises(InvalidParameterError, match="fallback"):
        ConformalMargin(0.1, horizon=2, fallback=-1.0)
    with pytest.raises(InvalidArrayError, match="scores"):
        margin.update_scores(1, [-0.1])
    with pytest.raises(InvalidParameterError, match="lookahead"):
        margin.margin(3)


def test_record_and_conformal_margin_cover_realised_positions_on_a_known_stream():
    # Obstacles move as random walks with Laplace steps around constant velocity;
    # the predictor is overconfident (N(0, 0.03^2) samples around the nominal path).
    # The conformal margin at k = 1 must still cover ||p - mu||, hence -h.p for every h,
    # with probability >= 1 - alpha: independent episodes, one test step each.
    rng = np.random.default_rng(4)
    alpha, horizon, n_obs, warmup, trials = 0.2, 3, 3, 12, 500
    velocity = np.array([[0.2, 0.0], [0.0, -0.2], [0.1, 0.1]])
    covered = 0
    hits_all_normals = 0
    for _ in range(trials):
        record = PredictionRecord(horizon=horizon)
        margin = ConformalMargin(alpha, horizon=horizon, gamma=0.0, fallback=10.0)
        p = rng.normal(size=(n_obs, 2))
        for _step in range(warmup):
            k = np.arange(1, horizon + 1)[None, None, :, None]
            samples = p[:, None, None, :] + k * velocity[:, None, None, :]
            samples = samples + 0.03 * rng.normal(size=(n_obs, 50, horizon, 2))
            margin.update(record.update(samples, p))
            issued, q = samples, margin.margin(1)
            p = p + velocity + rng.laplace(scale=0.05, size=(n_obs, 2))
        mu = issued[0, :, 0].mean(axis=0)
        covered += int(np.linalg.norm(p[0] - mu) <= q)
        h = rng.normal(size=2)
        h /= np.linalg.norm(h)
        hits_all_normals += int(-h @ p[0] <= -h @ mu + q)
    low, high = clopper_pearson(covered, trials)
    n_cal = (warmup - 1) * n_obs  # scores at k = 1 before the test step
    expected = conformal_rank(n_cal, alpha) / (n_cal + 1)
    assert low <= expected <= high
    assert hits_all_normals >= covered


# --------------------------------------------------------------------------- Wasserstein


def test_sliced_w1_equals_scipy_per_direction():
    rng = np.random.default_rng(5)
    a, b = rng.normal(size=(37, 2)), rng.laplace(size=(53, 2)) + 0.3
    angles = rng.uniform(0, np.pi, size=7)
    directions = np.stack([np.cos(angles), np.sin(angles)], axis=1)
    expected = [stats.wasserstein_distance(a @ h, b @ h) for h in directions]
    np.testing.assert_allclose(sliced_wasserstein_max(a, b, directions), expected, atol=1e-12)
    one_d = sliced_wasserstein_max(a[:, :1], b[:, :1], np.ones((1, 1)))
    assert one_d[0] == pytest.approx(stats.wasserstein_distance(a[:, 0], b[:, 0]), abs=1e-12)


@pytest.mark.parametrize("count", [4, 8, 32])
def test_grid_maximum_plus_slack_bounds_the_supremum_over_all_directions(count):
    rng = np.random.default_rng(count)
    for _ in range(5):
        a = rng.normal(size=(40, 2)) * rng.uniform(0.1, 1.0, size=2)
        b = rng.standard_t(3, size=(30, 2)) * 0.3 + rng.normal(size=2) * 0.2
        coarse, slack = grid_directions(2, count, "test")
        assert np.allclose(coarse, np.stack([np.cos(np.pi * np.arange(count) / count),
                                             np.sin(np.pi * np.arange(count) / count)], axis=1))
        fine_angles = np.linspace(0, np.pi, 2001)
        fine = np.stack([np.cos(fine_angles), np.sin(fine_angles)], axis=1)
        moments = np.linalg.norm(a, axis=1).mean() + np.linalg.norm(b, axis=1).mean()
        bound = sliced_wasserstein_max(a, b, coarse).max() + slack * moments
        assert sliced_wasserstein_max(a, b, fine).max() <= bound + 1e-12


def _w1_normal_vs_empirical(scale: float, shift: float, points: np.ndarray) -> float:
    """Exact W1 between N(shift, scale^2) and the empirical law of 1-D ``points``.

    W1 = sum_j int_{(j-1)/N}^{j/N} |Q(u) - y_(j)| du with Q(u) = shift + scale Phi^-1(u),
    whose antiderivative is shift u - scale phi(Phi^-1(u)).
    """
    y = np.sort(points) - shift
    n = y.size
    a, b = np.arange(n) / n, np.arange(1, n + 1) / n
    split = np.clip(ndtr(y / scale), a, b)

    def antiderivative(u):
        inner = ndtri(np.clip(u, 1e-300, 1 - 1e-16))
        value = -scale * np.exp(-0.5 * inner**2) / math.sqrt(2 * math.pi)
        return np.where((u <= 0) | (u >= 1), 0.0, value)

    left = -(antiderivative(split) - antiderivative(a) - y * (split - a))
    right = antiderivative(b) - antiderivative(split) - y * (b - split)
    return float(np.sum(left + right))


def test_exact_w1_reference_agrees_with_dense_sampling():
    points = np.random.default_rng(6).normal(size=50) * 0.3
    dense = ndtri((np.arange(200_000) + 0.5) / 200_000) * 0.2 + 0.05
    assert _w1_normal_vs_empirical(0.2, 0.05, points) == pytest.approx(
        stats.wasserstein_distance(points, dense), abs=2e-5)


@pytest.mark.slow
@pytest.mark.parametrize(
    "realised_std, bias, predicted_std",
    [(0.15, (0.0, 0.0), 0.1), (0.1, (0.06, -0.03), 0.1), (0.08, (0.0, 0.0), 0.12)],
)
def test_wasserstein_radius_covers_the_true_distance_at_its_confidence(
    realised_std, bias, predicted_std
):
    # Known laws: the realised position ~ N(bias, s^2 I) (isotropic, so every projection
    # is N(h.bias, s^2) and the true distance is exact); the filter's empirical law is a
    # fresh set of N_s predicted samples ~ N(0, sigma^2 I). The radius is estimated from
    # n realised errors and a pool of predicted errors, as a PredictionRecord gives them.
    rng = np.random.default_rng(7)
    confidence, n, n_s, trials = 0.9, 200, 100, 100
    bias = np.array(bias)
    angles = np.linspace(0, np.pi, 91)[:-1]  # h and -h give the same distance
    directions = np.stack([np.cos(angles), np.sin(angles)], axis=1)
    covered, ratios = 0, []
    for _ in range(trials):
        radius = WassersteinRadius(horizon=1, confidence=confidence, window=n,
                                   n_bootstrap=60, n_directions=16, seed=rng)
        predicted = rng.normal(size=(n // 10, n_s, 2)) * predicted_std
        means = predicted.mean(axis=1, keepdims=True)
        realised = bias + rng.normal(size=(n // 10, 10, 2)) * realised_std
        errors = (realised - means).reshape(-1, 2)
        radius.update_errors(1, errors, (predicted - means)[:, :10].reshape(-1, 2), n_samples=n_s)
        epsilon = radius.radius(1)
        centre = rng.normal(size=(n_s, 2)) * predicted_std  # the filter's samples at step t
        truth = max(_w1_normal_vs_empirical(realised_std, float(h @ bias), centre @ h)
                    for h in directions)
        covered += int(truth <= epsilon)
        ratios.append(epsilon / truth)
    low, high = clopper_pearson(covered, trials)
    assert high >= confidence  # not significantly below the intended coverage
    assert np.median(ratios) < 4.0  # and not uselessly conservative


def test_wasserstein_radius_fallback_cache_and_validation():
    rng = np.random.default_rng(8)
    radius = WassersteinRadius(horizon=2, fallback=0.05, min_errors=10, seed=0)
    assert radius.radii().tolist() == [0.05, 0.05]
    radius.update_errors(1, rng.normal(size=(12, 2)) * 0.1, rng.normal(size=(3, 20, 2)) * 0.1)
    first = radius.radius(1)
    assert first > 0.0 and radius.radius(2) == 0.05
    assert radius.radius(1) == first  # cached
    radius.update_errors(1, np.ones((1, 2)), np.zeros((1, 2)))
    assert radius.radius(1) == first  # still: recomputed after `refresh` (10) updates
    eager = WassersteinRadius(horizon=1, fallback=0.05, refresh=1, seed=0)
    eager.update_errors(1, rng.normal(size=(12, 2)) * 0.1, rng.normal(size=(20, 2)) * 0.1)
    before = eager.radius(1)
    eager.update_errors(1, np.full((1, 2), 3.0), np.zeros((1, 2)))
    assert eager.radius(1) > before  # an outlying error widens the radius at once
    same = WassersteinRadius(horizon=2, fallback=0.05, min_errors=10, seed=0)
    rng = np.random.default_rng(8)
    same.update_errors(1, rng.normal(size=(12, 2)) * 0.1, rng.normal(size=(3, 20, 2)) * 0.1)
    assert same.radius(1) == first  # seeded bootstrap: reproducible
    with pytest.raises(InvalidArrayError, match="d = 1 or 2"):
        WassersteinRadius(horizon=1).update_errors(1, np.zeros((3, 3)), np.zeros((4, 3)))
    for wrong in (np.zeros((4, 3)), 0.5):  # another d; a scalar (once an IndexError)
        with pytest.raises(InvalidArrayError, match="predicted_errors"):
            radius.update_errors(1, np.zeros((3, 2)), wrong)
    with pytest.raises(InvalidParameterError, match="confidence"):
        WassersteinRadius(horizon=1, confidence=1.0)


def test_wasserstein_radius_grows_with_the_mismatch_and_feeds_from_a_record():
    rng = np.random.default_rng(9)
    record = PredictionRecord(horizon=2)
    matched = WassersteinRadius(horizon=2, seed=1)
    truth = rng.normal(size=(2, 2))  # two stationary obstacles, noise N(0, 0.01 I)
    for _ in range(120):
        samples = truth[:, None, None, :] + 0.1 * rng.normal(size=(2, 50, 2, 2))
        realised = record.update(samples, truth + 0.1 * rng.normal(size=(2, 2)))
        matched.update(realised)
    # Realised errors at k: N(0, 0.01 (1 + 1/50)) vs predicted N(0, 0.01 (1 - 1/50)):
    # a well-specified predictor gets a small radius, far below a mis-specified one.
    small = matched.radii()
    wrong = WassersteinRadius(horizon=1, seed=1)
    wrong.update_errors(1, 0.3 * rng.normal(size=(200, 2)), 0.1 * rng.normal(size=(1000, 2)),
                        n_samples=50)
    assert np.all(small < 0.1)
    assert wrong.radius(1) > 0.15 > small.max()


def test_online_calibration_runs_on_environment_episodes_and_feeds_safe_halfspaces():
    import gymnasium as gym

    import safe_nav_env  # noqa: F401  (registers the ids)
    from filters import Disc, safe_halfspaces

    env = gym.make("SafeNav/RandomCrossing-v0")  # padded info: obstacle counts vary
    calibration = OnlineCalibration(horizon=10, alpha=0.2, wasserstein={"seed": 3})
    assert np.all(calibration.margins() == 1.0) and np.all(calibration.radii() == 0.05)
    for seed in range(3):
        _, info = env.reset(seed=seed)
        calibration.reset()
        for _ in range(15):
            present = info["obstacle_present"]
            calibration.update(info["predictions"], info["obstacle_positions"], present)
            samples = info["predictions"][present]
            n = samples.shape[0]
            for risk, options in (("conformal", {"conformal_margins": calibration.margins()}),
                                  ("dr_cvar", {"epsilon": calibration.radii()})):
                hs = safe_halfspaces(np.zeros((10, 2)), samples, ego_shape=Disc(0.3),
                                     obstacle_shapes=[Disc(0.3)] * n, risk=risk, **options)
                assert np.isfinite(hs.offsets).all()
            info = env.step(np.zeros(2))[4]
    margins, radii = calibration.margins(), calibration.radii()
    assert np.all(np.isfinite(margins)) and np.all(margins < 1.0)  # data replaced the fallback
    assert np.all(radii > 0) and np.all(np.diff(margins) > -0.05)  # wider further ahead
    assert calibration.conformal.n_scored.min() > 0


def test_online_calibration_with_present_pairs_rows_by_index_not_by_order():
    # Rows A, B, C of padded arrays; B leaves and C arrives in the same step, so two rows
    # are present both times. C must not be scored against B's prediction.
    rows = np.array([[0.0, 0.0], [10.0, 0.0], [20.0, 0.0]])
    samples = np.broadcast_to(rows[:, None, None, :], (3, 5, 4, 2)).copy()  # exact forecasts
    calibration = OnlineCalibration(horizon=4, alpha=0.2)
    calibration.update(samples, rows, np.array([True, True, False]))
    realised = calibration.update(samples, rows, np.array([True, False, True]))
    (one_step,) = realised
    assert one_step.ids.tolist() == [0]  # A only: C was not predicted a step ago
    assert one_step.scores.tolist() == [0.0]


def test_online_calibration_refuses_a_present_mask_of_another_length():
    calibration = OnlineCalibration(horizon=4, alpha=0.2)
    with pytest.raises(InvalidArrayError, match="present"):
        calibration.update(np.zeros((3, 5, 4, 2)), np.zeros((3, 2)), np.array([True, False]))
    with pytest.raises(InvalidArrayError, match="ids"):
        calibration.update(np.zeros((3, 5, 4, 2)), np.zeros((3, 2)), np.ones(3, bool), ids=[0, 1])
