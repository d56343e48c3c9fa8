"""Shared statistics of every fit: NRMSE, AIC/BIC, Jacobian CIs, correlation, whiteness."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from seafmu.identification.fitting import (
    aic_bic,
    ci_excludes_zero,
    confidence_intervals,
    correlation_matrix,
    covariance_from_jacobian,
    fit_statistics,
    nonidentifiable_pairs,
    nrmse,
    rmse,
    whiteness_test,
)


def test_nrmse_and_fit_percent_definitions() -> None:
    y = np.array([1.0, 2.0, 3.0, 4.0])
    assert nrmse(y, y) == 0.0
    assert nrmse(y, np.full(4, y.mean())) == pytest.approx(1.0)  # the mean is "0 % fit"
    assert nrmse(y, y + 0.5) == pytest.approx(1.0 / np.linalg.norm(y - y.mean()))
    assert rmse(np.array([3.0, 4.0]), 0) == pytest.approx(np.sqrt(12.5))
    assert rmse(np.array([3.0, 4.0, 0.0]), 1) == pytest.approx(np.sqrt(25 / 2))


def test_aic_prefers_the_true_model_only_when_the_gain_pays_for_the_parameter() -> None:
    aic1, bic1 = aic_bic(10.0, 100, 2)
    aic2, bic2 = aic_bic(9.9, 100, 3)  # 1 % less RSS for one more parameter: not worth it
    assert aic2 > aic1 and bic2 > bic1
    aic3, _ = aic_bic(5.0, 100, 3)
    assert aic3 < aic1 - 10


def test_linear_regression_intervals_match_the_textbook() -> None:
    rng = np.random.default_rng(4)
    x = np.linspace(0, 1, 40)
    X = np.column_stack([np.ones_like(x), x])
    y = 2.0 + 3.0 * x + rng.normal(0, 0.1, x.size)
    beta, *_ = np.linalg.lstsq(X, y, rcond=None)
    r = y - X @ beta
    cov = covariance_from_jacobian(X, r)
    s2 = r @ r / (40 - 2)
    np.testing.assert_allclose(cov, s2 * np.linalg.inv(X.T @ X), rtol=1e-10)
    ci = confidence_intervals(["a", "b"], beta, cov, 40)
    t = stats.t.ppf(0.975, 38)
    assert ci["b"][1] - beta[1] == pytest.approx(t * np.sqrt(cov[1, 1]))
    assert ci["a"][0] < 2.0 < ci["a"][1] and ci["b"][0] < 3.0 < ci["b"][1]
    assert ci_excludes_zero(ci["b"]) and not ci_excludes_zero((-1.0, 1.0))


def test_collinear_parameters_are_flagged_not_identifiable() -> None:
    rng = np.random.default_rng(0)
    x = rng.normal(size=200)
    J = np.column_stack([x, 2 * x + 1e-4 * rng.normal(size=200), rng.normal(size=200)])
    _, corr, nonid = fit_statistics(["p", "q", "r"], np.ones(3), J, rng.normal(size=200))
    assert ("p", "q") in nonid and all("r" not in pair for pair in nonid)
    assert abs(corr[0, 1]) > 0.95 and np.allclose(np.diag(corr), 1.0)
    exact = np.column_stack([x, 2 * x])  # singular: pseudo-inverse, correlation still +-1
    cov = covariance_from_jacobian(exact, rng.normal(size=200))
    assert nonidentifiable_pairs(["p", "q"], correlation_matrix(cov)) == [("p", "q")]


def test_whiteness_separates_white_from_coloured_residuals() -> None:
    rng = np.random.default_rng(1)
    e = rng.normal(size=2000)
    assert whiteness_test(e)["white"]
    ar = np.zeros(2000)
    for i in range(1, 2000):
        ar[i] = 0.9 * ar[i - 1] + e[i]
    w = whiteness_test(ar)
    assert not w["white"] and w["ljung_box_p"] < 1e-6 and w["fraction_outside"] > 0.5
