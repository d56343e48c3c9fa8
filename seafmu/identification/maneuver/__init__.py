"""Multi-DOF maneuver identification: M, D_L and D_Q of the full 3- or 6-DOF model from one log.

Model (Fossen; the same one ``components.vessel_model`` simulates, without current):

    M nu_dot + C(nu) nu + D_L nu + D_Q (|nu| * nu) + g(eta) = tau,     C(nu) nu linear in M

Two methods, as the identification brief asks:

- ``"ls"`` — the Minerva 2 study's equation-error least squares. ``nu_dot`` is measured or
  differentiated (Savitzky–Golay, or central differences), then, per DOF row,

      Y = nu_dot + M0^-1 (C_M0(nu) nu + g(eta)) = Theta^T [tau, nu, |nu| nu]

  gives M^-1, -M^-1 D_L, -M^-1 D_Q (full matrices, 3d regressors per row), hence M, D_L, D_Q.
  ``coriolis="vessel"`` takes M0 from the vessel file (the thesis's variant), ``"iterate"``
  recomputes C from the estimated M until it settles, and ``"joint"`` regresses the force form
  tau - g = M nu_dot + C_M(nu) nu + D_L nu + D_Q |nu| nu directly, which is linear in the
  entries of a symmetric M, so no prior M is needed. ``"joint"`` is required when the thrusters
  span fewer DOFs than the model (the AMV's two screws: tau_Y is proportional to tau_N, so
  M^-1 cannot be separated from its action on tau in the acceleration form).
- ``"output_error"`` — simulate the model against the measured nu and adjust the diagonal of
  D_L and D_Q (optionally the added-mass diagonal) by MINPACK's Levenberg-Marquardt on the
  Jacobian's block structure (``arrowlm``: linear in the log length), started from the LS
  estimate. Differentiating noisy data biases equation error; output error only ever compares
  simulated with measured velocities, so white sensor noise does not bias it.

Every fit reports in ``FitResult`` (``fitting.py``): parameters with 95 % intervals, correlation
and non-identifiable pairs, NRMSE of simulated nu on the fitted part and on the held-out last
``validation_fraction`` of the log, AIC/BIC, residual whiteness and physical-sanity warnings.
Simulation NRMSE is computed the same way for both methods (restarted segments, see
``_simulate``), so LS and output-error numbers are comparable. Method notes and verified
numbers: docs/maneuver_identification.md.

Package layout (one concern per module; ``from seafmu.identification.maneuver import X`` keeps
working for every name below):

- ``io`` — ``ManeuverData``, ``load_maneuver_csv`` (log checks, one line per problem),
  ``write_maneuver_csv``;
- ``excitation`` — multisines, ``simulate_maneuver`` (a trial flown by ``PlantBlock``),
  ``add_sensor_noise``;
- ``terms`` — Coriolis, restoring, the plant's matrices, the diagnosis extensions' names;
- ``preprocessing`` — resampling, noise ratio, nu_dot and the consistent smoothing;
- ``simulation`` — the batched RK4 simulator, segments, simulation NRMSE and traces;
- ``estimation`` — equation-error LS (both forms) and output error;
- ``statistics`` — residual autocorrelation, whiteness, physical sanity;
- ``fit`` — ``identify_maneuver``, the orchestration.
"""

from __future__ import annotations

from seafmu.identification.maneuver.estimation import (
    _ls_acceleration,
    _ls_joint,
    _LSResult,
    _output_error,
    _run_ls,
)
from seafmu.identification.maneuver.excitation import (
    add_sensor_noise,
    default_amplitude,
    multisine,
    simulate_maneuver,
)
from seafmu.identification.maneuver.fit import CORIOLIS, METHODS, identify_maneuver
from seafmu.identification.maneuver.io import (
    DOF_WORDS,
    SAMPLES_PER_REGRESSOR,
    ManeuverData,
    load_maneuver_csv,
    write_maneuver_csv,
)
from seafmu.identification.maneuver.preprocessing import DERIVATIVES, _prepare, _Prepared, noise_ratio
from seafmu.identification.maneuver.simulation import _nrmse_per_dof, _sim_setup, _SimSetup, _Simulator
from seafmu.identification.maneuver.terms import (
    MANEUVER_EFFECTS,
    _Restoring,
    _sym,
    coriolis_force,
    coriolis_tensor,
    effect_names,
    plant_matrices,
)
from seafmu.identification.trial import TrialError

__all__ = [
    "CORIOLIS", "DERIVATIVES", "DOF_WORDS", "MANEUVER_EFFECTS", "METHODS", "SAMPLES_PER_REGRESSOR",
    "ManeuverData", "TrialError", "_LSResult", "_Prepared", "_Restoring", "_SimSetup", "_Simulator",
    "_ls_acceleration", "_ls_joint", "_nrmse_per_dof", "_output_error", "_prepare", "_run_ls", "_sim_setup",
    "_sym", "add_sensor_noise", "coriolis_force", "coriolis_tensor", "default_amplitude", "effect_names",
    "identify_maneuver", "load_maneuver_csv", "multisine", "noise_ratio", "plant_matrices",
    "simulate_maneuver", "write_maneuver_csv",
]
