"""First-order wave loads from a JONSWAP sea on a small, mostly submerged vessel (long-wave Morison).

Sea state: long-crested, deep water, a sum of N regular components

    zeta(t, x) = sum_i a_i cos(omega_i t - k_i x_dir + phi_i),   k_i = omega_i^2 / g,
    a_i = sqrt(2 S(omega_i) d_omega)

with S the JONSWAP spectrum (DNV-RP-C205 form, normalised so that the integral is H_s^2 / 16),
x_dir the horizontal position along the direction the waves travel TOWARDS (``direction``, rad
from north, as the current's direction), omega_i one random frequency inside each of N equal bins
of [0.5, 4] omega_p (random, so the sum does not repeat after 2 pi / d_omega; the band holds
> 99.5 % of the variance for gamma in [1, 7]) and phi_i uniform random phases. All random numbers
come from one generator the plant seeds, drawn once at construction.

Loads: the vessel is small against the wave length (Minerva 2: about 2 m against 39 m at
T_p = 5 s) and the orbital motion is small against the body (Keulegan-Carpenter number
KC = u T / D ~ 0.3 at 5 m depth), so the flow is inertia dominated and drag on the orbital
velocity is left out. Per Morison / G. I. Taylor's long-wave theory the force is the
Froude-Krylov force of the pressure gradient plus the added-mass force, both on the undisturbed
fluid acceleration a at the vessel's centre of gravity:

    tau_wave = [ (m_d I + A_11) a_b ;  m_d r_b x a_b + A_21 a_b ],   a_b = R(Theta)^T a_ned

m_d is the displaced mass (buoyancy / g; a floating 3-DOF vessel: its mass), r_b the centre of
buoyancy, A_11 and A_21 the translational columns of the (symmetric part of the) added-mass
matrix. A neutrally buoyant body (m = m_d) then simply moves with the water when nothing holds it.
Deep-water particle accelerations at depth z (down, z >= 0; a vessel above the surface is
treated as at the surface):

    a_horizontal = -sum_i omega_i^2 a_i e^{-k_i z} sin(theta_i)   (along the wave direction)
    a_down       =  sum_i omega_i^2 a_i e^{-k_i z} cos(theta_i)

so the load dies out with depth as e^{-k z}: at T_p = 5 s (k_p = 0.16 /m) it is 45 % of the
surface value at 5 m, 20 % at 10 m and 4 % at 20 m. Not modelled: second-order (mean and slowly
varying) drift, wave spreading, radiation damping at wave frequency, finite water depth, the
surface-piercing hull of a surface vessel (3-DOF use is a crude horizontal-only approximation).
"""

from __future__ import annotations

import math

import numpy as np

from . import kernels
from .vessel_spec import VesselSpec

G = 9.81  # m/s^2
BAND = (0.5, 4.0)  # component frequencies span [BAND[0], BAND[1]] * omega_p
GAMMA_RANGE = (1.0, 7.0)  # where the DNV normalisation 1 - 0.287 ln(gamma) holds (within 2 %)


def jonswap(omega: np.ndarray | float, hs: float, tp: float, gamma: float = 3.3) -> np.ndarray:
    """JONSWAP wave spectrum S(omega) in m^2 s/rad (DNV-RP-C205 3.5.5); 0 at omega <= 0.

    S = A_gamma S_PM gamma^r, S_PM = 5/16 H_s^2 omega_p^4 omega^-5 exp(-5/4 (omega_p/omega)^4),
    r = exp(-(omega - omega_p)^2 / (2 sigma^2 omega_p^2)), sigma = 0.07 below omega_p, 0.09 above,
    A_gamma = 1 - 0.287 ln(gamma). gamma = 1 is the Pierson-Moskowitz spectrum.
    """
    w = np.atleast_1d(np.asarray(omega, dtype=float))
    wp = 2.0 * math.pi / tp
    out = np.zeros_like(w)
    pos = w > 0.0
    wv = w[pos]
    spm = 5.0 / 16.0 * hs**2 * wp**4 * wv**-5.0 * np.exp(-1.25 * (wp / wv) ** 4)
    sigma = np.where(wv <= wp, 0.07, 0.09)
    r = np.exp(-((wv - wp) ** 2) / (2.0 * sigma**2 * wp**2))
    out[pos] = (1.0 - 0.287 * math.log(gamma)) * spm * gamma**r
    return out if np.ndim(omega) else out[:1]


def check_sea(hs: float, tp: float, gamma: float, n: int) -> None:
    """ValueError naming the parameter if the sea state is not usable."""
    if not (math.isfinite(hs) and hs >= 0.0):
        raise ValueError(f"wave_hs must be >= 0, got {hs!r}")
    if not (math.isfinite(tp) and tp > 0.0):
        raise ValueError(f"wave_tp must be > 0, got {tp!r}")
    if not (GAMMA_RANGE[0] <= gamma <= GAMMA_RANGE[1]):
        raise ValueError(f"wave_gamma must be within [{GAMMA_RANGE[0]:g}, {GAMMA_RANGE[1]:g}], got {gamma!r}")
    if n < 1:
        raise ValueError(f"wave_components must be >= 1, got {n!r}")


class WaveField:
    """A seeded realisation of a long-crested JONSWAP sea: elevation and particle acceleration."""

    def __init__(self, hs: float, tp: float, direction: float, gamma: float, n: int,
                 rng: np.random.Generator) -> None:
        check_sea(hs, tp, gamma, n)
        wp = 2.0 * math.pi / tp
        lo, hi = BAND[0] * wp, BAND[1] * wp
        dw = (hi - lo) / n
        # Draw everything even for hs = 0, so a later non-zero hs gives the same sea.
        self.omega = lo + (np.arange(n) + rng.uniform(size=n)) * dw
        self.phase = rng.uniform(0.0, 2.0 * math.pi, size=n)
        self.k = self.omega**2 / G
        self.tp, self.gamma, self.direction = tp, gamma, direction
        self._unit_amp = np.sqrt(2.0 * jonswap(self.omega, 1.0, tp, gamma) * dw)  # per metre of H_s
        self._cd, self._sd = math.cos(direction), math.sin(direction)
        self.set_hs(hs)

    def set_hs(self, hs: float) -> None:
        """Change H_s keeping frequencies and phases (the spectrum scales with H_s^2)."""
        check_sea(hs, self.tp, self.gamma, len(self.omega))
        self.hs = float(hs)
        self.amp = self.hs * self._unit_amp
        self._acc_amp = self.amp * self.omega**2

    @property
    def variance(self) -> float:
        """Variance of the discretised elevation, sum a_i^2 / 2 (about H_s^2 / 16)."""
        return float(0.5 * np.sum(self.amp**2))

    def _theta(self, t: float, north: float, east: float) -> np.ndarray:
        return self.omega * t - self.k * (north * self._cd + east * self._sd) + self.phase

    def elevation(self, t: float, north: float = 0.0, east: float = 0.0) -> float:
        """Surface elevation (m, up) at time t above the horizontal position (north, east)."""
        return kernels.waves.elevation(float(t), float(north), float(east), self.omega, self.k, self.phase,
                                       self.amp, self._cd, self._sd)

    def acceleration(self, t: float, north: float, east: float, down: float) -> tuple[float, float, float]:
        """Undisturbed water-particle acceleration in NED (m/s^2) at a point ``down`` below the surface."""
        th = self._theta(t, north, east)
        att = self._acc_amp * np.exp(-self.k * max(down, 0.0))
        ah = -float(att @ np.sin(th))
        return ah * self._cd, ah * self._sd, float(att @ np.cos(th))


def load_matrix(vessel: VesselSpec) -> np.ndarray:
    """W with tau_wave = W a_b (a_b: fluid acceleration in the body frame, 3 values; 2 for 3 DOF)."""
    MA = 0.5 * (vessel.M_A + vessel.M_A.T)
    if vessel.dof == 6:
        rs = vessel.restoring
        if rs is None:
            raise ValueError(f"vessel '{vessel.name}': wave loads need a restoring section (buoyancy)")
        md = rs.buoyancy / G
        x, y, z = (float(c) for c in rs.r_b)
        fk = md * np.vstack([np.eye(3), [[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]]])  # [I; S(r_b)]
        return fk + MA[:, :3]
    md = float(vessel.M_RB[0, 0])  # a floating surface vessel displaces its own mass
    return md * np.array([[1.0, 0.0], [0.0, 1.0], [0.0, 0.0]]) + MA[:, :2]


class WaveLoad:
    """First-order wave force on one vessel: the sea (``WaveField``) times the load matrix."""

    def __init__(self, vessel: VesselSpec, field: WaveField) -> None:
        self.field = field
        self.dof = vessel.dof
        self.W = np.ascontiguousarray(load_matrix(vessel))

    def force(self, t: float, eta: np.ndarray | list[float]) -> list[float]:
        """Body-frame generalised wave force at time t for position/attitude ``eta``."""
        if self.field.hs == 0.0:
            return [0.0] * self.dof
        # a_b = R^T a_ned of the particle acceleration (``WaveField.acceleration``), then W a_b: compiled
        f = self.field
        out = np.empty(self.dof)
        kernels.waves.force(float(t), np.ascontiguousarray(eta, dtype=float), self.dof, f.omega, f.k, f.phase,
                            f._acc_amp, f._cd, f._sd, self.W, out)
        return out.tolist()
