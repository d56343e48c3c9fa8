"""The three real data sets shipped in scenarios/data: the published numbers, honestly reported."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from seafmu.identification.diagnosis import diagnose, identify
from seafmu.identification.trial import load_trial

DATA = Path(__file__).resolve().parents[1] / "scenarios" / "data"


def test_amv_osf_tow_test_reproduces_the_thesis_fit_and_flags_negative_damping() -> None:
    trial = load_trial(DATA / "amv_osf_tow_resistance.yaml")
    ident = identify(trial)
    f = ident.fit
    assert f.n_samples == 15  # 8 speeds mirrored to negative ones, zero once
    assert f.params["d_L"] == pytest.approx(-0.6587, abs=5e-5)
    assert f.params["d_Q"] == pytest.approx(34.08, abs=5e-3)
    assert f.extras["rmse"] == pytest.approx(0.04411, abs=5e-6)  # n - p in the denominator
    assert any("negative linear damping" in w for w in f.warnings)
    assert f.ci95["d_L"][1] < 0  # the negative term is significant, not noise
    assert "RMSE 0.04411" in " ".join(ident.notes)


def test_rov_cfd_table_names_quadratic_damping_against_a_linear_baseline() -> None:
    trial = load_trial(DATA / "rov_cfd_force_speed.yaml")
    assert trial.baseline == "linear"
    d = diagnose(trial)
    assert d.baseline.extras["rmse_plain"] == pytest.approx(5.4, abs=0.1)  # the linear model misses badly
    assert d.effect == "quadratic_damping"
    ext = d.extended
    assert ext.params["d_L"] == pytest.approx(15.62, abs=0.01)
    assert ext.params["d_Q"] == pytest.approx(42.73, abs=0.01)
    assert ext.extras["rmse_plain"] == pytest.approx(0.27, abs=0.005)
    j = d.to_json()
    assert j["gain"]["validation_nrmse_ratio"] > 10 and j["gain"]["delta_aic"] < -40
    assert "quadratic" in j["cause"]["evidence"]


def test_rov_cfd_linear_quadratic_identification_agrees_with_the_paper() -> None:
    trial = load_trial(DATA / "rov_cfd_force_speed.yaml")
    trial.baseline = "linear_quadratic"
    f = identify(trial).fit
    assert f.params == pytest.approx({"d_L": 15.62, "d_Q": 42.73}, abs=0.01)
    assert all(lo > 0 for lo, _ in f.ci95.values())  # both terms significant ...
    assert f.nonidentifiable == [("d_L", "d_Q")]  # ... but strongly correlated over 0.1-1 m/s
    assert f.warnings == ["d_L and d_Q are correlated (r = -0.969): not separately identifiable "
                          "from this data"]
    assert diagnose(trial).effect == "none"  # nothing left to explain


def test_pendulum_swing_equation_error_and_what_differentiation_does() -> None:
    trial = load_trial(DATA / "pendulum_free_decay.yaml")
    assert trial.runs[0].n == 18
    ident = identify(trial)
    pub = ident.alternatives["equation_error_published_rates"]
    dif = ident.alternatives["equation_error_differentiated_theta"]
    # With the authors' smoothed rates the law comes out physical: restoring, positive damping.
    assert pub.params["alpha"] == pytest.approx(-3.82, abs=0.01)
    assert pub.params["beta"] == pytest.approx(0.862, abs=0.005)
    assert pub.params["gamma"] == pytest.approx(1.634, abs=0.005)
    assert not [w for w in pub.warnings if "correlated" not in w]
    assert pub.nonidentifiable  # one half-swing: alpha, beta, gamma strongly correlated (flagged)
    # Differentiating the quantised angle twice gives an unphysical model, flagged as such.
    assert dif.params["alpha"] > 0 and dif.params["beta"] < 0
    assert any("unstable" in w for w in dif.warnings)
    assert dif.nrmse_fit > 3 * pub.nrmse_fit
    # Output error on 18 samples of a half-swing: wide intervals, honest about it.
    oe = ident.fit
    assert any(lo < 0 < hi for lo, hi in oe.ci95.values())
    assert any("quantis" in n for n in ident.notes)
    assert np.isfinite(oe.nrmse_fit) and oe.nrmse_fit < 0.2


def test_real_data_do_not_produce_false_alarms() -> None:
    for name in ("amv_osf_tow_resistance", "pendulum_free_decay"):
        assert diagnose(load_trial(DATA / f"{name}.yaml")).effect == "none"
