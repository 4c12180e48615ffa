"""The guarantee audit: losses, activity, pooled CVaR and violation frequency on known laws."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.stats import norm

from agents.errors import RecordsFileError
from agents.evaluation.audit import (
    AUDIT_TOLERANCE,
    audit_losses,
    cluster_bootstrap,
    decode_losses,
    encode_losses,
    first_step_losses,
)
from agents.evaluation.records import EpisodeRecord, read_records, write_records
from agents.evaluation.summary import audit_rows, audit_table, wilson_interval
from filters import Disc, safe_halfspaces
from filters.errors import InvalidArrayError, InvalidParameterError
from filters.risk import empirical_cvar


def test_first_step_losses_by_hand():
    normals = np.array([[1.0, 0.0], [0.0, -1.0], [0.6, 0.8]])
    offsets = np.array([1.0, 2.0, 0.5])
    y1 = np.array([1.0 - 0.5 * AUDIT_TOLERANCE, -1.0])  # on row 0; 1 m inside row 1; beyond 2
    realised = np.array([[1.5, 3.0], [0.0, -2.4], [1.0, 1.0]])
    radii = np.array([0.6, 0.6, 0.5])
    active, losses = first_step_losses(normals, offsets, y1, realised, radii)
    # slack b - h.y1: 0.0005, 2 - 1 = 1, 0.5 - (0.6 - 0.8) = 0.7
    np.testing.assert_array_equal(active, [True, False, False])
    # loss b + r - h.p: 1 + 0.6 - 1.5, 2 + 0.6 - 2.4, 0.5 + 0.5 - 1.4
    np.testing.assert_allclose(losses, [0.1, 0.2, -0.4], atol=1e-12)
    # the inter-sample bow margin widens the test; a violated row (negative slack) is active
    active, _ = first_step_losses(normals, offsets, y1, realised, radii,
                                  margins=np.array([0.0, 0.999, 0.0]))
    np.testing.assert_array_equal(active, [True, True, False])
    # y = (3, -3): slacks 1 - 3 = -2, 2 - 3 = -1 (violated: active), 0.5 + 0.6 = 1.1
    active, _ = first_step_losses(normals, offsets, np.array([3.0, -3.0]), realised, radii)
    np.testing.assert_array_equal(active, [True, True, False])


def test_first_step_losses_rejects_bad_input():
    h, b, y, p, r = np.eye(2), np.ones(2), np.zeros(2), np.zeros((2, 2)), np.ones(2)
    with pytest.raises(InvalidArrayError, match="realised_positions must have shape"):
        first_step_losses(h, b, y, np.zeros((3, 2)), r)
    with pytest.raises(InvalidArrayError, match="offsets must be finite"):
        first_step_losses(h, np.array([1.0, np.nan]), y, p, r)
    with pytest.raises(InvalidParameterError, match="tolerance"):
        first_step_losses(h, b, y, p, r, tolerance=-1.0)


def test_audit_of_a_gaussian_law_matches_the_closed_forms():
    """Losses ~ N(mu, s²): CVaR_a = mu + s phi(z_{1-a}) / a, P(l > d) = 1 - Phi((d - mu)/s)."""
    rng = np.random.default_rng(7)
    mu, s, alpha, delta = -0.05, 0.1, 0.2, 0.1
    losses = rng.normal(mu, s, 400_000)
    result = audit_losses(losses, alpha=alpha, delta=delta)
    z = norm.ppf(1 - alpha)
    assert result.n == losses.size
    assert result.cvar_loss == pytest.approx(mu + s * norm.pdf(z) / alpha, abs=2e-3)
    assert result.mean_loss == pytest.approx(mu, abs=1e-3)
    truth = 1 - norm.cdf((delta - mu) / s)
    assert result.violation_low <= truth <= result.violation_high
    assert result.violation_high - result.violation_low < 0.01
    assert result.violations == int(np.count_nonzero(losses > delta))


def test_wilson_interval_of_the_violation_frequency_covers_the_truth():
    """Over 400 independent audits of n = 200 steps, about 95 % of the intervals cover p."""
    rng = np.random.default_rng(3)
    truth = 1 - norm.cdf(1.0)  # P(N(0, 1) > 1) = 0.159
    covered = 0
    for _ in range(400):
        result = audit_losses(rng.normal(0.0, 1.0, 200), alpha=0.2, delta=1.0)
        covered += result.violation_low <= truth <= result.violation_high
    low, high = wilson_interval(covered, 400)
    assert low <= 0.95 <= high + 0.01  # Wilson is near-nominal at n = 200


@pytest.mark.parametrize("risk", ["gaussian_cc", "cvar"])
def test_the_promise_holds_when_the_predictions_are_the_law(risk):
    """Halfspace from Gaussian samples, realised positions from the same Gaussian:
    gaussian_cc's violation frequency is alpha, cvar's realised CVaR is delta."""
    rng = np.random.default_rng(11)
    alpha, delta, sigma = 0.2, 0.1, 0.1
    mean = np.array([2.0, 0.5])
    samples = mean + sigma * rng.standard_normal((1, 20_000, 1, 2))
    reference = np.zeros((1, 2))
    hs = safe_halfspaces(reference, samples, ego_shape=Disc(0.3), obstacle_shapes=[Disc(0.3)],
                         risk=risk, alpha=alpha, delta=delta)
    h, b = hs.normals[0, 0], hs.offsets[0, 0]
    realised = mean + sigma * rng.standard_normal((50_000, 2))
    losses = np.array([first_step_losses(h[None], np.array([b]), reference[0], p[None],
                                         np.array([0.6]))[1][0] for p in realised[:2000]])
    # the vectorised form equals the per-step function on the first 2000
    all_losses = b + 0.6 - realised @ h
    np.testing.assert_allclose(losses, all_losses[:2000], atol=1e-12)
    result = audit_losses(all_losses, alpha=alpha, delta=delta)
    # Under the true law the loss is N(m, sigma²) with m = b + r - h.mean (|h| = 1).
    m = b + 0.6 - h @ mean
    if risk == "gaussian_cc":
        truth = 1 - norm.cdf((delta - m) / sigma)
        assert truth == pytest.approx(alpha, abs=0.01)  # the halfspace is calibrated
        assert result.violation_low <= truth <= result.violation_high
    else:
        truth = m + sigma * norm.pdf(norm.ppf(1 - alpha)) / alpha
        assert truth == pytest.approx(delta, abs=5e-3)
        assert result.cvar_loss == pytest.approx(truth, abs=5e-3)
    # A bias the predictions do not know (0.1 m towards the ego) breaks the promise.
    biased = audit_losses(all_losses + 0.1, alpha=alpha, delta=delta)
    assert biased.verdict("chance" if risk == "gaussian_cc" else "cvar") == "violated"
    assert biased.violation_low > alpha


def test_audit_losses_validation_and_empty():
    empty = audit_losses([], alpha=0.2, delta=0.1)
    assert empty.n == 0 and math.isnan(empty.cvar_loss) and empty.verdict("cvar") == "-"
    with pytest.raises(InvalidParameterError, match="alpha"):
        audit_losses([0.0], alpha=0.0, delta=0.1)
    with pytest.raises(InvalidParameterError, match="delta"):
        audit_losses([0.0], alpha=0.2, delta=math.nan)
    with pytest.raises(InvalidArrayError):
        audit_losses([0.0, math.inf], alpha=0.2, delta=0.1)


def test_encode_decode_round_trip():
    values = np.array([0.123456789, -1.5e-7, 3.0])
    text = encode_losses(values)
    assert text == "0.1235;0;3"  # rounded to 0.1 mm
    np.testing.assert_allclose(decode_losses(text), values, atol=5e-5)
    assert decode_losses("").size == 0
    with pytest.raises(RecordsFileError, match="audit_losses"):
        decode_losses("0.1;x")
    with pytest.raises(RecordsFileError, match="finite"):
        decode_losses("0.1;nan")


def _record(risk, seed, losses, **kw):
    return EpisodeRecord(scenario="Custom", risk=risk, seed=seed, planner="ppo",
                         reference="rollout", alpha=0.2, delta=0.1, case="biased",
                         audit_steps=len(losses), audit_losses=encode_losses(losses),
                         audit_all_steps=len(losses) + 1,
                         audit_all_losses=encode_losses([*losses, -1.0]), **kw)


def test_audit_rows_pool_episodes_through_the_csv(tmp_path):
    """Pooled over episodes (after a CSV round trip): the CVaR of all losses, not a mean."""
    a, b = [0.3, -0.2, 0.0], [0.05, 0.2]
    records = [_record("cvar", 0, a, epsilon=0.05), _record("cvar", 1, b, epsilon=0.05),
               _record("dr_cvar", 0, [0.15], epsilon="auto"),
               _record("none", 0, [], epsilon=0.05)]
    path = tmp_path / "episodes.csv"
    write_records(path, records)
    back = read_records(path)
    assert back == records and back[2].epsilon == "auto"
    rows = audit_rows(back)
    assert [(r.scenario, r.method) for r in rows] == [("biased", "cvar"),
                                                      ("biased", "dr_cvar (eps=auto)")]
    pooled = rows[0].active
    assert pooled.n == 5
    assert pooled.cvar_loss == pytest.approx(float(empirical_cvar(np.array(a + b), 0.2)))
    assert pooled.cvar_loss == pytest.approx(0.3)  # alpha N = 1: the largest loss
    assert pooled.violations == 2
    every = rows[0].all  # plus one loss of -1 m per episode
    assert every.n == 7 and every.mean_loss == pytest.approx((0.35 - 2.0) / 7)
    assert every.cvar_loss == pytest.approx(float(empirical_cvar(np.array(a + b + [-1, -1]),
                                                                 0.2)))
    table = audit_table(rows)
    # every bootstrap replicate (a, a / a, b / b, b) has its CVaR above delta
    assert pooled.cvar_low > 0.1 and pooled.verdict("cvar") == "violated"
    assert "| biased | ppo | cvar | CVaR_α ℓ ≤ δ | 0.2 | 0.1 | 5 | 0.070 [" in table
    assert "**0.300 [" in table


@pytest.mark.slow
def test_episode_audit_matches_a_step_by_step_recomputation():
    """The runner's audit columns equal the losses recomputed by hand from info and the env."""
    from agents.evaluation.records import EpisodeSpec
    from agents.evaluation.runner import make_env, run_episode
    from filters.intersample import arc_margin

    # turning, DR-CVaR with the online radius, no held-out calibration (radius 0.05 m
    # until data): the shipped policy meets an active step-1 halfspace at seed 9
    spec = EpisodeSpec("Custom", "dr_cvar", 9, epsilon="auto", case="turning",
                       filter_options={"calibration_episodes": 0})
    record, _ = run_episode(spec)
    assert record.error == ""
    env, planner = make_env(spec)
    obs, _ = env.reset(seed=9)
    base = env.unwrapped
    every, active = [], []
    done = False
    while not done:
        action, _ = planner.predict(obs, deterministic=True)
        obs, _, terminated, truncated, info = env.step(action)
        report = info["filter"]
        done = terminated or truncated
        for i in range(len(base.obstacle_radii)):
            h, b = report.normals[i, 0], report.offsets[i, 0]
            p = np.asarray(info["obstacle_positions"][i])
            loss = b + base.ego_radius + base.obstacle_radii[i] - h @ p
            every.append(loss)
            y1 = report.planned_states[1, :2]
            if b - h @ y1 <= arc_margin(h, base.input_bounds, base.dt) + AUDIT_TOLERANCE:
                active.append(loss)
    env.close()
    assert record.audit_all_steps == len(every) == 2 * record.steps
    assert len(active) >= 1
    np.testing.assert_allclose(decode_losses(record.audit_all_losses), every, atol=5.1e-5)
    assert record.audit_steps == len(active)
    np.testing.assert_allclose(decode_losses(record.audit_losses), active, atol=5.1e-5)


def test_cluster_bootstrap_covers_the_mean_of_correlated_episodes():
    """Episodes share a random offset: resampling episodes covers the truth about 95 %."""
    rng = np.random.default_rng(5)
    covered = 0
    naive = 0
    for _ in range(100):
        groups = [rng.normal(rng.normal(), 0.2, 20) for _ in range(40)]
        low, high = cluster_bootstrap(groups, np.mean, n_boot=200, seed=1)
        covered += low <= 0.0 <= high
        pooled = np.concatenate(groups)  # an interval that treats the steps as independent
        half = 1.96 * pooled.std(ddof=1) / math.sqrt(pooled.size)
        naive += abs(pooled.mean()) <= half
    assert covered >= 85
    assert naive < 70  # and why it is needed: the independent-steps interval undercovers


def test_cluster_bootstrap_known_answers():
    assert cluster_bootstrap([np.array([0.3])] * 5, np.mean) == pytest.approx((0.3, 0.3),
                                                                                    abs=1e-15)
    low, high = cluster_bootstrap([np.zeros(0), np.zeros(0)], np.mean)
    assert math.isnan(low) and math.isnan(high)
    # the same seed gives the same interval
    groups = [np.arange(3.0), np.arange(5.0), np.array([7.0])]
    assert cluster_bootstrap(groups, np.mean, seed=4) == cluster_bootstrap(
        groups, np.mean, seed=4)
    result = audit_losses([], groups=groups, alpha=0.5, delta=10.0)
    assert result.n == 9 and result.mean_low <= result.mean_loss <= result.mean_high
    assert result.cvar_low <= result.cvar_loss <= result.cvar_high
    assert result.verdict("cvar") == "held"
