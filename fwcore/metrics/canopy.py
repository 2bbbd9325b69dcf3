"""Canopy cover, plant area index and its vertical profile (GEDI L2B), from the canopy's and the ground's share of
a waveform's energy.

    rg           the ground's energy: the area of an extended Gaussian (the transmitted pulse's shape) fitted to
                 the waveform's lower part, centred near the lowest mode (L2B algorithm 1)
    rv           the canopy's energy: what the waveform holds above that ground return, above the ground
    Pgap         1 - rv / (rv + rhov/rhog * rg): the gap probability at the beam's angle (rhov/rhog 1.5 by default,
                 L2B's 0.6 / 0.4)
    cover        cos(zenith) (1 - Pgap)
    PAI          -ln(Pgap) cos(zenith) / (rossg omega): rossg 0.5 (random leaf angles), omega 1 (no clumping)
    pai_z        the PAI above each height of a 5 m grid from the ground; PAVD = -d pai_z / dz (m2/m3)
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
from numba import njit

from fwcore._jit import JIT

RHOV_RHOG = 0.6 / 0.4  # L2B's default reflectances of vegetation and ground
ROSSG = 0.5
OMEGA = 1.0
PROFILE_STEP_M = 5.0
PROFILE_TOP_M = 150.0  # L2B's maxheight_cuttoff: 30 bins of 5 m
TAIL_SAMPLES = 150  # fitted beyond the signal's last sample


@dataclasses.dataclass(frozen=True)
class CanopySettings:
    """L2B's constants: the vegetation-to-ground reflectance ratio, the projection and clumping of the elements,
    and the profile's bins."""

    rhov_rhog: float = RHOV_RHOG
    rossg: float = ROSSG
    omega: float = OMEGA
    profile_step_m: float = PROFILE_STEP_M
    profile_top_m: float = PROFILE_TOP_M

    @property
    def profile_heights(self) -> np.ndarray:
        """The heights (m above the ground) at the bottom of each profile bin: 0, 5, ... 145."""
        return np.arange(int(round(self.profile_top_m / self.profile_step_m))) * self.profile_step_m


@dataclasses.dataclass(frozen=True)
class GroundPulse:
    """The extended (exponentially modified) Gaussian a ground return is fitted with, in samples: the transmitted
    pulse's sigma and decay rate gamma, and their errors (the fit keeps sigma above sigma - 3 errors and gamma
    within 3 errors, as L2B's algorithm 1 does with L1B's tx_egsigma and tx_eggamma)."""

    sigma: float
    sigma_error: float
    gamma: float
    gamma_error: float

    @classmethod
    def gaussian_like(cls, sigma: float) -> "GroundPulse":
        """For a sensor whose transmitted pulse is known only by its width: any sigma above 0, a short tail."""
        return cls(sigma, sigma / 3.0, 1.0, 0.3)


@njit(**JIT)
def _extended_gaussian_at(amplitude, centre, sigma, gamma, x):
    spread = gamma * sigma * sigma
    y = amplitude * 0.5 * gamma * math.exp(gamma * (centre + 0.5 * spread - x)) * \
        math.erfc((centre + spread - x) / max(1e-12, math.sqrt(2.0) * sigma))
    return y if math.isfinite(y) else 0.0


@njit(**JIT)
def _terms(p, x, y, limit, growth, tail):
    """_cost, keeping each sample's exp and erfc terms (growth, tail) for the Jacobian at p; it stops once the sum
    reaches `limit` (a rejected trial: the terms left only add to it)."""
    amplitude, centre, sigma, gamma = p[0], p[1], p[2], p[3]
    spread = gamma * sigma * sigma
    scale = max(1e-12, math.sqrt(2.0) * sigma)
    total = 0.0
    for i in range(x.size):
        growth[i] = math.exp(gamma * (centre + 0.5 * spread - x[i]))
        tail[i] = math.erfc((centre + spread - x[i]) / scale)
        value = amplitude * 0.5 * gamma * growth[i] * tail[i]  # _extended_gaussian_at's, in its order
        r = (value if math.isfinite(value) else 0.0) - y[i]
        total += r * r
        if total >= limit:
            return total
    return total


@njit(**JIT)
def _residual_and_jacobian(p, x, y, growth, tail, residual, jac):
    """The model minus y at x, and its derivatives in amplitude, centre, sigma and gamma (analytic), from the exp
    and erfc terms _terms kept at p."""
    amplitude, centre, sigma, gamma = p[0], p[1], p[2], p[3]
    root2 = math.sqrt(2.0)
    for i in range(x.size):
        v = (centre + gamma * sigma * sigma - x[i]) / max(1e-12, root2 * sigma)
        e = growth[i]
        f = tail[i]
        df = -2.0 / math.sqrt(math.pi) * math.exp(-v * v)  # d erfc(v) / dv
        half = 0.5 * amplitude * gamma * e
        value = half * f
        if not (math.isfinite(value) and math.isfinite(df * half)):
            residual[i] = -y[i]
            jac[i, 0] = jac[i, 1] = jac[i, 2] = jac[i, 3] = 0.0
            continue
        residual[i] = value - y[i]
        jac[i, 0] = 0.5 * gamma * e * f
        jac[i, 1] = half * (gamma * f + df / (root2 * sigma))
        jac[i, 2] = half * (gamma * gamma * sigma * f + df * (-(centre - x[i]) / (root2 * sigma * sigma) + gamma / root2))
        jac[i, 3] = 0.5 * amplitude * e * f + half * ((centre + gamma * sigma * sigma - x[i]) * f + df * sigma / root2)


@njit(**JIT)
def _solve4(a, b, out):
    """a (k x k, symmetric positive definite after damping) \\ b by Gaussian elimination with partial pivoting, in
    place: for four unknowns a LAPACK call costs more than the arithmetic."""
    k = b.size
    m = a.copy()
    r = b.copy()
    for c in range(k):
        pivot = c
        for i in range(c + 1, k):
            if abs(m[i, c]) > abs(m[pivot, c]):
                pivot = i
        if pivot != c:
            for j in range(k):
                m[c, j], m[pivot, j] = m[pivot, j], m[c, j]
            r[c], r[pivot] = r[pivot], r[c]
        for i in range(c + 1, k):
            f = m[i, c] / m[c, c]
            for j in range(c, k):
                m[i, j] -= f * m[c, j]
            r[i] -= f * r[c]
    for c in range(k - 1, -1, -1):
        acc = r[c]
        for j in range(c + 1, k):
            acc -= m[c, j] * out[j]
        out[c] = acc / m[c, c]


@njit(**JIT)
def _fit_extended_gaussian(x, y, p, lower, upper, iterations):
    """Levenberg-Marquardt on the four parameters, analytic Jacobian, a parameter its gradient holds at a bound
    kept there and each step projected into the bounds; stops when a step no longer lowers the cost by a
    relative 1e-9 or after `iterations` steps."""
    n, k = x.size, 4
    jac = np.empty((n, k))
    residual = np.empty(n)
    trial = np.empty(k)
    delta = np.empty(k)
    # the exp and erfc terms at p, and at the trial: an accepted trial's are the next Jacobian's
    growth, tail, trial_growth, trial_tail = np.empty(n), np.empty(n), np.empty(n), np.empty(n)
    cost = _terms(p, x, y, np.inf, growth, tail)
    damping = 1e-3
    for _ in range(iterations):
        _residual_and_jacobian(p, x, y, growth, tail, residual, jac)
        normal = np.zeros((k, k))
        gradient = np.zeros(k)
        for i in range(n):
            for j in range(k):
                gradient[j] += jac[i, j] * residual[i]
                for l in range(j, k):
                    normal[j, l] += jac[i, j] * jac[i, l]
        for j in range(k):
            for l in range(j):
                normal[j, l] = normal[l, j]
        for j in range(k):  # a parameter held at a bound by its gradient stays there: the step is in the others
            if (p[j] <= lower[j] and gradient[j] > 0) or (p[j] >= upper[j] and gradient[j] < 0):
                normal[j, :] = 0.0
                normal[:, j] = 0.0
                normal[j, j] = 1.0
                gradient[j] = 0.0
        improved = False
        new_cost = cost
        for _ in range(30):
            a = normal.copy()
            for j in range(k):
                a[j, j] += damping * max(normal[j, j], 1e-12)
            _solve4(a, -gradient, delta)
            for j in range(k):
                trial[j] = min(max(p[j] + delta[j], lower[j]), upper[j])
            new_cost = _terms(trial, x, y, cost, trial_growth, trial_tail)
            if new_cost < cost:
                improved = True
                growth, trial_growth = trial_growth, growth
                tail, trial_tail = trial_tail, tail
                break
            damping *= 10.0
        if not improved:
            break
        relative = (cost - new_cost) / max(cost, 1e-300)
        p[:] = trial
        cost = new_cost
        damping = max(damping / 10.0, 1e-12)
        if relative < 1e-9:
            break
    return p


@njit(**JIT)
def _extended_gaussian(p, x, out):
    for i in range(x.size):
        out[i] = _extended_gaussian_at(p[0], p[1], p[2], p[3], x[i])


def extended_gaussian(params: np.ndarray, x: np.ndarray) -> np.ndarray:
    """amplitude (its area), centre, sigma, gamma -> the exponentially modified Gaussian at x (L2B's form)."""
    x = np.ascontiguousarray(x, dtype=np.float64)
    out = np.empty(x.size)
    _extended_gaussian(np.asarray(params, dtype=np.float64), x, out)
    return out


def ground_return(signal: np.ndarray, ground: float, pulse: GroundPulse,
                  centre_buffer: float = 4.0) -> tuple[np.ndarray, float]:
    """The ground return fitted to `signal` (the waveform above the noise, zero outside the signal) below
    ground - 2 centre_buffer, its centre within centre_buffer samples of the ground: the model at every sample,
    and its area rg.

    Sample i sits at i + 1 in the fit, as in NASA's L2B (a 1-based index against L2A's 0-based zcross): with it
    this reproduces L2B's rv and rg; without it both are off by 5-70 %."""
    x = np.arange(1, signal.size + 1, dtype=np.float64)
    # below the signal the samples are 0 and so, 150 samples on, is the model (its tail e^-(gamma 150) < 1e-8):
    # those samples add nothing to the fit but time
    last_signal = np.flatnonzero(signal)[-1] + 1 if signal.any() else signal.size
    fitted = (x > ground - 2 * centre_buffer) & (x <= last_signal + TAIL_SAMPLES)
    lower = np.array([-np.inf, ground - centre_buffer, pulse.sigma - 3 * pulse.sigma_error,
                      pulse.gamma - 3 * pulse.gamma_error])
    upper = np.array([np.inf, ground + centre_buffer, np.inf, pulse.gamma + 3 * pulse.gamma_error])
    start = np.clip([signal.max(), ground, pulse.sigma, pulse.gamma], lower + 1e-9, upper - 1e-9)
    p = _fit_extended_gaussian(x[fitted], np.ascontiguousarray(signal[fitted], dtype=np.float64),
                               start.astype(np.float64), lower, upper, 100)
    return extended_gaussian(p, x), float(p[0])


def canopy_energy(signal: np.ndarray, ground_model: np.ndarray, ground: float) -> np.ndarray:
    """The canopy's energy per sample: what the signal holds above the ground return, above the ground (0 below);
    its sum is rv (L2B's definition, 1-based like its fit)."""
    x = np.arange(1, signal.size + 1, dtype=np.float64)
    return np.where(x < ground, np.maximum(signal - ground_model, 0.0), 0.0)


def gap_probability(rv, rg, rhov_rhog=RHOV_RHOG):
    """Pgap(theta) = 1 - rv / (rv + rhov/rhog rg); 1 (all gap) where there is no energy."""
    rv, rg = np.asarray(rv, dtype=np.float64), np.asarray(rg, dtype=np.float64)
    denominator = rv + rhov_rhog * rg
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(denominator > 0, 1.0 - rv / denominator, 1.0)


def canopy_cover(pgap, cos_zenith):
    """The vertically projected canopy cover: cos(zenith) (1 - Pgap(theta)), as L2B computes it."""
    return np.asarray(cos_zenith) * (1.0 - np.asarray(pgap))


def plant_area_index(pgap, cos_zenith, rossg=ROSSG, omega=OMEGA):
    """PAI = -ln(Pgap) cos(zenith) / (rossg omega) (m2/m2); infinite where Pgap is 0 (no ground seen)."""
    with np.errstate(divide="ignore"):
        return -np.log(np.asarray(pgap, dtype=np.float64)) * np.asarray(cos_zenith) / (rossg * omega)


def vertical_profile(heights: np.ndarray, canopy: np.ndarray, rv: float, rg: float, cos_zenith: float,
                     settings: CanopySettings = CanopySettings()) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """cover_z, pai_z (the cover and PAI above each profile height) and pavd_z (m2/m3), from the canopy energy per
    sample and each sample's height above the ground (samples from the top down): at each profile height, the gap
    probability after the canopy down to the first sample at or below it (L2B's extraction)."""
    bins = settings.profile_heights
    denominator = rv + settings.rhov_rhog * rg
    pgap = 1.0 - np.cumsum(canopy) / denominator if denominator > 0 else np.ones(canopy.size)
    first_below = np.argmax(heights[None, :] <= bins[:, None], axis=1)  # 0 where no sample is that low
    pgap_z = np.where(bins < heights.max() if heights.size else False, pgap[first_below], 1.0)
    pgap_z = np.clip(pgap_z, 0.0, 1.0)
    cover_z = canopy_cover(pgap_z, cos_zenith)
    pai_z = plant_area_index(pgap_z, cos_zenith, settings.rossg, settings.omega)
    pavd_z = -np.gradient(pai_z, settings.profile_step_m) if bins.size > 1 else np.zeros(bins.size)
    return cover_z, pai_z, pavd_z
