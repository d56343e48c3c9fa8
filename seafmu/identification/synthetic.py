"""Synthetic trials with one catalogue effect hidden in them (``demo_trial``).

The data come from the fitter's own models (``timeseries.simulate``, ``static.StaticModel``) with
10 RK4 sub-steps per sample, so the truth lies inside the fitted model class; ``plant_trials``
makes the same kind of trial with seafmu's full plant instead. Used by tests/test_ident_hidden.py,
the CLI's demo trials and the benchmarks.
"""

from __future__ import annotations

import numpy as np

from seafmu.identification import static, timeseries
from seafmu.identification.trial import Run, Trial, make_trial

# Truth of the synthetic surge vessel: AMV-like (40 kg + 10 kg added mass, d_Q = 34.08, k = 12.63).
SURGE = {"M": 50.0, "d_L": 3.0, "d_Q": 34.0, "k": 12.63}


def demo_trial(effect: str | None, kind: str | None = None, noise: float = 0.01, amplitude: float = 1.0,
               seed: int = 0) -> Trial:
    """A synthetic trial in which `effect` is hidden (None: clean data of `kind`).

    Each effect gets the trial kind where it is observable, with an effect size a real vessel
    could have. noise is the sensor noise std as a fraction of the largest |output|; amplitude
    scales the excitation (initial speed/angle or command levels). Data are simulated with 10 RK4
    sub-steps per sample, so the fit (one step per sample) does not share the generator's
    discretisation.
    """
    # Over 80 lines: one branch per trial kind, each a few lines of truth values and excitation; the
    # per-effect lines are the effects' hidden values (docs/architecture.md, "Identification: where
    # changes go", plans to move them into one object per effect).
    rng = np.random.default_rng(seed)
    A = amplitude
    kind = kind or (_DESIGN[effect] if effect else "decay")
    if kind not in DEMO_EFFECTS:
        raise ValueError(f"demo kind '{kind}': one of {', '.join(DEMO_EFFECTS)}")
    if effect is not None and effect not in DEMO_EFFECTS[kind]:
        raise ValueError(f"demo: '{effect}' is not hidden in a '{kind}' trial "
                         f"(there: {', '.join(sorted(DEMO_EFFECTS[kind]))})")
    fam = {"decay": "first", "step": "first", "decay2": "second", "pendulum": "pendulum",
           "sway_yaw": "sway_yaw", "static": "static", "thrust": "static"}[kind]
    truth = dict(timeseries.DEFAULTS.get(fam, {}))
    baseline = "linear_quadratic"
    constants: dict[str, float] = {}
    name = f"hidden_{effect or 'none'}_{kind}"

    def noisy(y: np.ndarray) -> np.ndarray:
        scale = np.max(np.abs(y), axis=0)
        return y + rng.normal(0.0, 1.0, y.shape) * noise * scale

    if kind in ("static", "thrust"):
        if kind == "static":
            x = A * np.linspace(0.1, 1.0, 16)
            v = {"d_L": 15.6, "d_Q": 42.7}
            if effect == "quadratic_damping":
                baseline = "linear"
            elif effect == "linear_damping":
                baseline = "quadratic"
            m = static.StaticModel("force_speed", "linear", [], v)
            y = m.predict(x)
            return make_trial("static", [Run("table", noisy(y), u=x)], dof="surge", table="force_speed",
                              baseline=baseline, name=name)
        x = A * np.array([-2.2, -1.8, -1.4, -1.0, -0.6, -0.3, 0.3, 0.6, 1.0, 1.4, 1.8, 2.2])
        v = {"k": 12.63}
        law = "linear"
        if effect == "thrust_quadratic":
            v = {"k": 0.0, "k_q": 6.0}
        elif effect == "thrust_asymmetry":
            v["eta_rev"] = -0.35
        elif effect == "deadband":
            v["n_0"] = 0.25 * A
        elif effect == "saturation":
            v["u_sat"] = 0.7 * 2.2 * A
        elif effect == "constant_force":
            v["F_0"] = 1.5
        y = static.StaticModel("thrust_rpm", law, [], v).predict(x)
        return make_trial("static", [Run("bollard", noisy(y), u=x)], dof="surge", table="thrust_rpm",
                          baseline="linear", name=name)

    if kind == "sway_yaw":
        truth.update(m22=91.4, m66=25.4, Y_v=-60.0, N_r=-20.0)
        if effect == "coupling":
            truth.update(Y_r=12.0, N_v=6.0)
        constants = {"mass": 91.4, "inertia": 25.4}
        model = timeseries.TSModel("sway_yaw", truth, [], "force")
        runs = []
        for i, pattern in enumerate(([20, 0, -20, 10, 0], [-10, 25, 0, -25, 5])):
            t = np.arange(0, 40.0, 0.1)
            seg = np.minimum((t // 8).astype(int), 4)
            Y = A * np.array(pattern, dtype=float)[seg]
            N = A * 0.3 * np.array(pattern[::-1], dtype=float)[(seg + 1) % 5]
            u = np.column_stack([Y, N])
            y = timeseries.simulate(model, truth, t, u, (0.0, 0.0), substeps=10)
            runs.append(Run(f"run{i + 1}", noisy(y), t, u))
        return make_trial("step", runs, dof="sway_yaw", baseline="linear", constants=constants, name=name)

    if kind == "pendulum":
        truth.update(alpha=-4.0, beta=0.8, gamma=1.6)
        if effect == "coulomb_friction":
            truth["f_c"] = 0.06
        elif effect == "constant_force":
            truth["F_0"] = 0.15
        model = timeseries.TSModel("pendulum", truth, [], restoring="sin")
        t = np.arange(0, 14.0, 1 / 30)
        runs = [Run(f"release{i + 1}", noisy(timeseries.simulate(model, truth, t, None, (th0, 0.0), 10)), t)
                for i, th0 in enumerate((0.5 * A, -0.35 * A, 0.42 * A))]
        return make_trial("pendulum", runs, dof="surge", baseline="pendulum", name=name)

    if kind == "decay2":
        truth.update(M=5.0, c=20.0, d_L=0.5)
        constants = {"mass": 5.0}
        restoring = "linear"
        if effect == "nonlinear_restoring":
            restoring = "sin"
        elif effect == "quadratic_damping":
            truth["d_Q"] = 3.0
        elif effect == "coulomb_friction":
            truth["f_c"] = 0.15
        elif effect == "constant_force":
            truth["F_0"] = 0.8
        elif effect == "added_mass":
            truth["m_a"] = 1.5
            constants["stiffness"] = 20.0
        baseline = "linear"
        model = timeseries.TSModel("second", truth, [], restoring=restoring)
        t = np.arange(0, 25.0, 0.05)
        runs = [Run(f"release{i + 1}", noisy(timeseries.simulate(model, truth, t, None, (x0, 0.0), 10)), t)
                for i, x0 in enumerate((0.75 * A, -0.5 * A))]
        return make_trial("decay2", runs, dof="roll", baseline=baseline, constants=constants, name=name)

    truth.update(SURGE)
    constants = {"mass": SURGE["M"]}
    if kind == "decay":
        starts = (1.0 * A, 0.6 * A)
        if effect == "linear_damping":
            truth["d_L"] = 8.0
            baseline = "quadratic"
        elif effect == "quadratic_damping":
            baseline = "linear"
        elif effect in ("current", "constant_force", "coulomb_friction"):
            starts = (1.0 * A, -1.0 * A, 0.7 * A)
            truth.update({"current": {"v_c": 0.1}, "constant_force": {"F_0": 1.0},
                          "coulomb_friction": {"f_c": 1.0}}[effect])
        model = timeseries.TSModel("first", truth, [])
        t = np.arange(0, 25.0, 0.1)
        runs = [Run(f"coast{i + 1}", noisy(timeseries.simulate(model, truth, t, None, (v0,), 10)), t)
                for i, v0 in enumerate(starts)]
        return make_trial("decay", runs, dof="surge", baseline=baseline, constants=constants, name=name)

    # step trials with a shaft-speed command (or a force command for added mass)
    input_kind = "rpm"
    law = "linear"
    levels = [(1.0, 2.0, 0.5, -1.0, -2.0, 0.0), (1.5, 0.8, -1.5, 2.2, 0.3, -0.6)]
    if effect == "thrust_quadratic":
        truth.update(k=6.0)
        law = "quadratic"
    elif effect == "thrust_asymmetry":
        truth["eta_rev"] = -0.35
    elif effect == "deadband":
        truth["n_0"] = 0.3 * A
        levels = [(1.0, 2.0, 0.4, -1.0, -2.0, -0.4), (1.5, 0.6, -1.5, 2.2, 0.3, -0.6)]
    elif effect == "actuator_lag":
        truth["T_lag"] = 0.8
    elif effect == "time_delay":
        truth["t_d"] = 0.5
    elif effect == "saturation":
        truth["u_sat"] = 1.4 * A
    elif effect == "constant_force":
        truth["F_0"] = 1.5
    elif effect == "added_mass":
        input_kind = "force"
        constants = {"mass": 40.0}
        truth.update(M=40.0, m_a=12.0)
        levels = [(20.0, 40.0, 10.0, -20.0, -40.0, 0.0), (30.0, 15.0, -30.0, 45.0, 5.0, -10.0)]
    model = timeseries.TSModel("first", truth, [], input_kind, law)
    runs = []
    for i, lv in enumerate(levels):
        t = np.arange(0, 48.0, 0.1)
        u = A * np.array(lv)[np.minimum((t // 8).astype(int), len(lv) - 1)]
        y = timeseries.simulate(model, truth, t, u, (0.0,), substeps=10)
        runs.append(Run(f"steps{i + 1}", noisy(y), t, u))
    return make_trial("step", runs, dof="surge", baseline=baseline, constants=constants, name=name,
                      input_kind=input_kind)


# effect -> the trial kind where demo_trial hides it by default (where it is observable)
_DESIGN: dict[str, str] = {
    "linear_damping": "decay", "quadratic_damping": "decay", "coulomb_friction": "pendulum",
    "current": "decay", "constant_force": "step", "added_mass": "step",
    "thrust_quadratic": "step", "thrust_asymmetry": "step", "deadband": "step",
    "actuator_lag": "step", "time_delay": "step", "saturation": "step",
    "nonlinear_restoring": "decay2", "coupling": "sway_yaw",
}
# kind -> effects demo_trial can hide in it ("static": force-speed table, "thrust": bollard table)
DEMO_EFFECTS: dict[str, set[str]] = {
    "static": {"linear_damping", "quadratic_damping"},
    "thrust": {"thrust_quadratic", "thrust_asymmetry", "deadband", "saturation", "constant_force"},
    "decay": {"linear_damping", "quadratic_damping", "current", "constant_force", "coulomb_friction"},
    "step": {"thrust_quadratic", "thrust_asymmetry", "deadband", "actuator_lag", "time_delay", "saturation",
             "constant_force", "added_mass"},
    "decay2": {"nonlinear_restoring", "quadratic_damping", "coulomb_friction", "constant_force",
               "added_mass"},
    "pendulum": {"coulomb_friction", "constant_force"},
    "sway_yaw": {"coupling"},
}
