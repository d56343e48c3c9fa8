"""Synthetic trials with one catalogue effect hidden in them (``demo_trial``).

The data come from the fitter's own models (``timeseries.simulate``, ``static.StaticModel``) with
10 RK4 sub-steps per sample, so the truth lies inside the fitted model class; ``plant_trials``
makes the same kind of trial with seafmu's full plant instead. Used by tests/test_ident_hidden.py,
the CLI's demo trials and the benchmarks.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from seafmu.identification import effects, static, timeseries
from seafmu.identification.catalogue import CATALOGUE
from seafmu.identification.effects.base import Hiding
from seafmu.identification.trial import Run, Trial, make_trial

# Truth of the synthetic surge vessel: AMV-like (40 kg + 10 kg added mass, d_Q = 34.08, k = 12.63).
SURGE = {"M": 50.0, "d_L": 3.0, "d_Q": 34.0, "k": 12.63}


def _hiding(effect: str | None, kind: str, A: float) -> Hiding:
    """The effect object's hiding of itself in a trial of ``kind`` (clean: nothing)."""
    if effect is None:
        return Hiding()
    obj = effects.get(effect)
    assert obj is not None, effect
    return obj.hide(kind, A)


def merge_hidings(names: tuple[str, ...], hidings: list[Hiding]) -> Hiding:
    """Several effects hidden in one trial: their truths and constants together; a trial setting
    (baseline, starts, levels, laws) that two of them set differently cannot be shared."""
    fields = ("baseline", "starts", "levels", "restoring", "thrust_law", "input_kind", "trial_restoring",
              "vessel")
    merged: dict[str, object] = {}
    for f in fields:
        vals = [(n, getattr(h, f)) for n, h in zip(names, hidings, strict=True) if getattr(h, f) is not None]
        if len({repr(v) for _, v in vals}) > 1:
            raise ValueError(f"demo: {' and '.join(n for n, _ in vals)} cannot be hidden together "
                             f"(each sets the trial's {f.replace('_', ' ')} differently)")
        merged[f] = vals[0][1] if vals else None
    truth: dict[str, float] = {}
    constants: dict[str, float] = {}
    plant: dict[str, float] = {}
    for h in hidings:
        truth.update(h.truth)
        constants.update(h.constants)
        plant.update(h.plant)
    return Hiding(truth=truth, constants=constants, plant=plant, **merged)  # type: ignore[arg-type]


def demo_trial(effect: str | tuple[str, ...] | None, kind: str | None = None, noise: float = 0.01,
               amplitude: float = 1.0, seed: int = 0) -> Trial:
    """A synthetic trial in which `effect` is hidden — one name, several names at once (a tuple), or
    None for clean data of `kind`.

    Each effect gets the trial kind where it is observable, with an effect size a real vessel
    could have (the effect object's ``hide``). noise is the sensor noise std as a fraction of the
    largest |output|; amplitude scales the excitation (initial speed/angle or command levels).
    Data are simulated with 10 RK4 sub-steps per sample, so the fit (one step per sample) does not
    share the generator's discretisation.
    """
    rng = np.random.default_rng(seed)
    A = amplitude
    names = (effect,) if isinstance(effect, str) else tuple(effect or ())
    kinds = demo_effects()
    kind = kind or (_design()[names[0]] if names else "decay")
    if kind not in kinds:
        raise ValueError(f"demo kind '{kind}': one of {', '.join(kinds)}")
    for e in names:
        if e not in kinds[kind]:
            raise ValueError(f"demo: '{e}' is not hidden in a '{kind}' trial "
                             f"(there: {', '.join(sorted(kinds[kind]))})")
    if len(names) > 1:
        hid = merge_hidings(names, [_hiding(e, kind, A) for e in names])
    else:
        hid = _hiding(names[0] if names else None, kind, A)
    name = f"hidden_{'+'.join(names) or 'none'}_{kind}"

    def noisy(y: np.ndarray) -> np.ndarray:
        scale = np.max(np.abs(y), axis=0)
        return y + rng.normal(0.0, 1.0, y.shape) * noise * scale

    return _KINDS[kind](hid, A, noisy, name)


Noisy = Callable[[np.ndarray], np.ndarray]


def _static(hid: Hiding, A: float, noisy: Noisy, name: str) -> Trial:
    """Force-speed table of the pendulum paper's CFD (K_L 15.6, K_Q 42.7)."""
    x = A * np.linspace(0.1, 1.0, 16)
    y = static.StaticModel("force_speed", "linear", [], {"d_L": 15.6, "d_Q": 42.7, **hid.truth}).predict(x)
    return make_trial("static", [Run("table", noisy(y), u=x)], dof="surge", table="force_speed",
                      baseline=hid.baseline or "linear_quadratic", name=name)


def _thrust(hid: Hiding, A: float, noisy: Noisy, name: str) -> Trial:
    """Bollard-pull table of one AMV screw (k 12.63 N/rps), ahead and astern."""
    x = A * np.array([-2.2, -1.8, -1.4, -1.0, -0.6, -0.3, 0.3, 0.6, 1.0, 1.4, 1.8, 2.2])
    y = static.StaticModel("thrust_rpm", "linear", [], {"k": 12.63, **hid.truth}).predict(x)
    return make_trial("static", [Run("bollard", noisy(y), u=x)], dof="surge", table="thrust_rpm",
                      baseline="linear", name=name)


def _sway_yaw(hid: Hiding, A: float, noisy: Noisy, name: str) -> Trial:
    """Coupled sway-yaw force steps (AAUSHIP-like)."""
    truth = {**timeseries.DEFAULTS["sway_yaw"], "m22": 91.4, "m66": 25.4, "Y_v": -60.0, "N_r": -20.0,
             **hid.truth}
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
    return make_trial("step", runs, dof="sway_yaw", baseline="linear",
                      constants={"mass": 91.4, "inertia": 25.4}, name=name)


def _pendulum(hid: Hiding, A: float, noisy: Noisy, name: str) -> Trial:
    """Three releases of the pendulum rig (alpha -4, beta 0.8, gamma 1.6)."""
    truth = {**timeseries.DEFAULTS["pendulum"], "alpha": -4.0, "beta": 0.8, "gamma": 1.6, **hid.truth}
    model = timeseries.TSModel("pendulum", truth, [], restoring="sin")
    t = np.arange(0, 14.0, 1 / 30)
    runs = [Run(f"release{i + 1}", noisy(timeseries.simulate(model, truth, t, None, (th0, 0.0), 10)), t)
            for i, th0 in enumerate((0.5 * A, -0.35 * A, 0.42 * A))]
    return make_trial("pendulum", runs, dof="surge", baseline="pendulum", name=name)


def _decay2(hid: Hiding, A: float, noisy: Noisy, name: str) -> Trial:
    """Roll releases of a 5 kg·m², 20 N·m/rad rig with a linear-restoring baseline."""
    truth = {**timeseries.DEFAULTS["second"], "M": 5.0, "c": 20.0, "d_L": 0.5, **hid.truth}
    model = timeseries.TSModel("second", truth, [], restoring=hid.restoring or "linear")
    t = np.arange(0, 25.0, 0.05)
    runs = [Run(f"release{i + 1}", noisy(timeseries.simulate(model, truth, t, None, (x0, 0.0), 10)), t)
            for i, x0 in enumerate((0.75 * A, -0.5 * A))]
    return make_trial("decay2", runs, dof="roll", baseline=hid.baseline or "linear",
                      constants={"mass": 5.0, **hid.constants}, name=name)


def _decay(hid: Hiding, A: float, noisy: Noisy, name: str) -> Trial:
    """Surge coast-downs of the synthetic AMV-like vessel."""
    truth = {**timeseries.DEFAULTS["first"], **SURGE, **hid.truth}
    model = timeseries.TSModel("first", truth, [])
    t = np.arange(0, 25.0, 0.1)
    runs = [Run(f"coast{i + 1}", noisy(timeseries.simulate(model, truth, t, None, (s * A,), 10)), t)
            for i, s in enumerate(hid.starts or (1.0, 0.6))]
    return make_trial("decay", runs, dof="surge", baseline=hid.baseline or "linear_quadratic",
                      constants={"mass": SURGE["M"], **hid.constants}, name=name)


def _step(hid: Hiding, A: float, noisy: Noisy, name: str) -> Trial:
    """Shaft-speed (or force) staircases of the synthetic AMV-like vessel."""
    truth = {**timeseries.DEFAULTS["first"], **SURGE, **hid.truth}
    input_kind = hid.input_kind or "rpm"
    model = timeseries.TSModel("first", truth, [], input_kind, hid.thrust_law or "linear")
    runs = []
    levels = hid.levels or ((1.0, 2.0, 0.5, -1.0, -2.0, 0.0), (1.5, 0.8, -1.5, 2.2, 0.3, -0.6))
    for i, lv in enumerate(levels):
        t = np.arange(0, 48.0, 0.1)
        u = A * np.array(lv)[np.minimum((t // 8).astype(int), len(lv) - 1)]
        # from rest, the first command switched on at t = 0 (as the fit reads such a run)
        y = timeseries.simulate(model, truth, t, u, (0.0,), substeps=10, before=0.0)
        runs.append(Run(f"steps{i + 1}", noisy(y), t, u))
    return make_trial("step", runs, dof="surge", baseline=hid.baseline or "linear_quadratic",
                      constants={"mass": SURGE["M"], **hid.constants}, name=name, input_kind=input_kind)


# kind -> how demo_trial makes it ("static": force-speed table, "thrust": bollard table)
_KINDS: dict[str, Callable[[Hiding, float, Noisy, str], Trial]] = {
    "static": _static, "thrust": _thrust, "decay": _decay, "step": _step, "decay2": _decay2,
    "pendulum": _pendulum, "sway_yaw": _sway_yaw,
}


def demo_effects() -> dict[str, set[str]]:
    """kind -> effects demo_trial can hide in it (each effect object's ``demo_kinds``)."""
    return {k: {o.name for o in effects.all_effects() if k in o.demo_kinds and o.name in CATALOGUE}
            for k in _KINDS}


def _design() -> dict[str, str]:
    """effect -> the trial kind where demo_trial hides it by default (its first demo kind)."""
    return {o.name: o.demo_kinds[0] for o in effects.all_effects() if o.demo_kinds and o.name in CATALOGUE}


DEMO_EFFECTS: dict[str, set[str]] = demo_effects()
