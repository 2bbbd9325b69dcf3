"""Slow, obviously-correct references for the numba kernels (the stumpy habit), in plain NumPy and SciPy.

None imports the code it checks: the model, the optimizers and the filters are written again from their
equations. `fwcore.rng.SplitMix64` is the one import of fwcore: the population references draw from the same
random stream as the kernels so that one generation can be compared value for value.
"""

from __future__ import annotations

import numpy as np

from fwcore.rng import SplitMix64

SQRT_2LN2 = np.sqrt(2.0 * np.log(2.0))


def model_of_individual(x: np.ndarray, t: np.ndarray) -> np.ndarray:
    """[b, (A, u, s, alpha)...] -> b + sum A exp(-ln2 (|t - u| / h)**(alpha**2)), h = s sqrt(2 ln 2) the
    half width at half maximum of the equal-FWHM Gaussian sigma s, in float64."""
    t = np.asarray(t, dtype=float)
    y = np.full(t.shape, float(x[0]))
    for a, u, s, alpha in np.asarray(x[1:], dtype=float).reshape(-1, 4):
        y += a * np.exp(-np.log(2.0) * (np.abs(t - u) / (s * SQRT_2LN2)) ** (alpha * alpha))
    return y


def gaussian_smooth(samples: np.ndarray, sigma: float) -> np.ndarray:
    """Normalized convolution with a +-4 sigma Gaussian, all samples valid."""
    half = int(np.ceil(4 * sigma))
    w = np.exp(-0.5 * (np.arange(-half, half + 1) / sigma) ** 2)
    num = np.convolve(samples, w, mode="same")
    den = np.convolve(np.ones_like(samples), w, mode="same")
    return num / den


def _repair(v, base, lo, hi):
    return np.where(v < lo, 0.5 * (lo + base), np.where(v > hi, 0.5 * (hi + base), v))


def _partners(rng: SplitMix64, np_: int, i: int, count: int) -> list[int]:
    out: list[int] = []
    while len(out) < count:
        r = rng.randint(np_)
        if r != i and r not in out:
            out.append(r)
    return out


def _chaotic(rng: SplitMix64, t: int, k: int, a: float, b: float) -> list[float]:
    out = []
    for _ in range(t):
        z = (a + (b - a) * rng.uniform() - a) / (b - a)
        for _ in range(k):
            z = 4.0 * z * (1.0 - z)
            out.append(a + z * (b - a))
    return out


def mde_generation(pop, fitness, lower, upper, cr, t, k, a, b, rng: SplitMix64, objective):
    """One generational MDE step, drawing from the same random stream as the kernel."""
    np_, d = pop.shape
    best = int(np.argmin(fitness))
    new_pop, new_fit = pop.copy(), fitness.copy()
    for i in range(np_):
        r1, r2, r3, r4 = _partners(rng, np_, i, 4)
        f1s = _chaotic(rng, t, k, a, b)
        f2s = _chaotic(rng, t, k, a, b)
        candidates = [_repair(pop[best] + f1 * (pop[r1] - pop[r2]) + f2 * (pop[r3] - pop[r4]),
                              pop[best], lower, upper) for f1, f2 in zip(f1s, f2s)]
        errors = [objective(v) for v in candidates]
        mutant = candidates[int(np.argmin(errors))]
        jrand = rng.randint(d)
        take = np.array([rng.uniform() < cr or j == jrand for j in range(d)])
        trial = np.where(take, mutant, pop[i])
        err = objective(trial)
        if err <= fitness[i]:
            new_pop[i], new_fit[i] = trial, err
    return new_pop, new_fit


def pso_swarm(pop, fitness, lower, upper, generations, rng: SplitMix64, objective):
    """Global-best PSO with Clerc's constriction (w 0.7298, c1 = c2 = 1.49618), speed within 0.2 of each
    range, positions clipped to the box; pop and fitness become the personal bests, drawing from the same
    random stream as the kernel. Returns the evaluations."""
    pop, fitness = pop.copy(), fitness.copy()
    np_, d = pop.shape
    span = upper - lower
    velocity = np.array([[(2.0 * rng.uniform() - 1.0) * 0.1 * span[j] for j in range(d)] for _ in range(np_)])
    x = pop.copy()
    best = int(np.argmin(fitness))
    for _ in range(generations):
        for i in range(np_):
            for j in range(d):
                r1 = rng.uniform()
                r2 = rng.uniform()
                v = (0.7298 * velocity[i, j] + 1.49618 * r1 * (pop[i, j] - x[i, j])
                     + 1.49618 * r2 * (pop[best, j] - x[i, j]))
                velocity[i, j] = np.clip(v, -0.2 * span[j], 0.2 * span[j])
                x[i, j] = np.clip(x[i, j] + velocity[i, j], lower[j], upper[j])
            err = objective(x[i])
            if err <= fitness[i]:
                pop[i], fitness[i] = x[i], err
                best = i if err < fitness[best] else best
    return pop, fitness, generations * np_


def ga_generation(pop, fitness, lower, upper, crossover_rate, mutation_rate, rng: SplitMix64, objective):
    """One generation of the real-coded GA: the elite kept first, then children of two binary tournaments,
    BLX-0.5 blended with probability crossover_rate, each parameter mutated with probability mutation_rate by
    0.1 of its range times a Box-Muller normal, clipped to the box; the kernel's random stream."""
    def tournament():
        a, b = rng.randint(fitness.size), rng.randint(fitness.size)
        return a if fitness[a] <= fitness[b] else b

    def normal():
        u1 = max(rng.uniform(), 1e-300)
        return np.sqrt(-2.0 * np.log(u1)) * np.cos(2.0 * np.pi * rng.uniform())

    elite = int(np.argmin(fitness))
    new_pop, new_fit = [pop[elite].copy()], [fitness[elite]]
    for _ in range(1, pop.shape[0]):
        p1, p2 = pop[tournament()], pop[tournament()]
        blend = rng.uniform() < crossover_rate
        child = np.empty(pop.shape[1])
        for j in range(child.size):
            v = p1[j] + (rng.uniform() * 2.0 - 0.5) * (p2[j] - p1[j]) if blend else p1[j]
            if rng.uniform() < mutation_rate:
                v += 0.1 * (upper[j] - lower[j]) * normal()
            child[j] = min(max(v, lower[j]), upper[j])
        new_pop.append(child)
        new_fit.append(objective(child))
    return np.array(new_pop), np.array(new_fit)


def _convolve_same(x, kernel, centre):
    """sum_j kernel[j] x[i - (j - centre)]: the response placed at every sample, zero outside."""
    return np.convolve(x, kernel)[centre:centre + x.size]


def _correlate_same(x, kernel, centre):
    """The convolution's adjoint: sum_j kernel[j] x[i + (j - centre)]."""
    start = kernel.size - 1 - centre
    return np.convolve(x, kernel[::-1])[start:start + x.size]


def richardson_lucy(signal, kernel, centre, iterations, floor=1e-12):
    """x <- x * (h~ * (y / (h * x))) from a flat start at the signal's mean."""
    x = np.full(signal.size, max(signal.mean(), floor))
    for _ in range(iterations):
        x = x * _correlate_same(signal / np.maximum(_convolve_same(x, kernel, centre), floor), kernel, centre)
    return x


def gold(signal, kernel, centre, iterations, floor=1e-12):
    """x <- x * (h~ * y) / (h~ * h * x) from a flat start at the signal's mean."""
    x = np.full(signal.size, max(signal.mean(), floor))
    numerator = _correlate_same(signal, kernel, centre)
    for _ in range(iterations):
        x = x * numerator / np.maximum(_correlate_same(_convolve_same(x, kernel, centre), kernel, centre), floor)
    return x


def gaussian_response_kernel(pulse_sigma):
    """A Gaussian of pulse_sigma samples over +-4 sigma, unit area, and the index of its time 0."""
    half = int(np.ceil(4.0 * pulse_sigma))
    kernel = np.exp(-0.5 * (np.arange(-half, half + 1) / pulse_sigma) ** 2)
    return kernel / kernel.sum(), half


def noise_variance(smoothed, valid, background, noise, shape_tolerance):
    """sigma^2 + (shape_tolerance x signal)^2 per valid sample, signal the smoothed height above background."""
    signal = np.maximum(np.asarray(smoothed)[valid] - background, 0.0)
    return noise ** 2 + (shape_tolerance * signal) ** 2


def shot_noise(model, raw, signal, variance):
    """The Poisson-like g >= 0 whose g x signal explains, by least squares over samples with signal, the
    squared residuals the variance leaves; returns g and the variance with g x max(signal, 0) added."""
    has = signal > 0
    den = np.sum(signal[has] ** 2)
    g = max(np.sum(signal[has] * ((model - raw)[has] ** 2 - variance[has])) / den, 0.0) if den > 0 else 0.0
    return g, variance + g * np.maximum(signal, 0.0)


def parameter_bounds(background, noise, amplitude, position, sigma, signal, first, last, gaussian, alpha_min,
                     alpha_max, scale, table_widths=None):
    """The start x0 and the boxes (lower, upper, the local methods' upper) of [b, (A, u, s, alpha)...]:
    b within max(3 noise, scale); A in [0, 1.5 A + 3 noise] (local: 1.5 max(A, height at u) + 3 noise);
    u within max(1.5 s, 2) inside [first, last]; s in [max(s / 4, 0.3), 3 s], or a table's rows
    (table_widths = (narrowest, widest)) with the start clipped into them; alpha sqrt(2), fixed if gaussian."""
    x0, lower, upper, local = [background], [background - max(3 * noise, scale)], [], []
    upper.append(background + max(3 * noise, scale))
    local.append(upper[0])
    for a, u, s in zip(amplitude, position, sigma):
        height = signal[min(max(int(round(u)), 0), len(signal) - 1)] - background
        shift = max(1.5 * s, 2.0)
        s_lo, s_hi, s0 = max(0.25 * s, 0.3), 3.0 * s, s
        if table_widths is not None:
            s_lo, s_hi = table_widths
            s0 = min(max(s, s_lo), s_hi)
        a_lo, a_hi = (np.sqrt(2), np.sqrt(2)) if gaussian else (alpha_min, alpha_max)
        x0 += [a, u, s0, np.sqrt(2)]
        lower += [0.0, max(first, u - shift), s_lo, a_lo]
        upper += [1.5 * a + 3 * noise, min(last, u + shift), s_hi, a_hi]
        local += [1.5 * max(a, height) + 3 * noise, upper[-3], s_hi, a_hi]
    return np.array(x0), np.array(lower), np.array(upper), np.array(local)


__all__ = ["SQRT_2LN2", "model_of_individual", "gaussian_smooth", "mde_generation", "pso_swarm", "ga_generation",
           "richardson_lucy", "gold", "gaussian_response_kernel", "noise_variance", "shot_noise", "parameter_bounds",
           "mark_spurious", "progressive_echoes", "chi2_without_echo", "model_jacobian", "least_squares_fit",
           "lbfgs_fit", "patent_peaks", "gaussian_individual"]


def mark_spurious(amplitude, position, width, first, last, pulse_fwhm, noise, min_snr, min_ratio,
                  min_separation, min_width, max_width, first_echo_ratio=1.0) -> list[str]:
    """The filter's rules, one echo at a time (echoes sorted by position)."""
    largest = max(amplitude, default=0.0)
    reasons = []
    for a, u, w in zip(amplitude, position, width):
        if a <= 0 or a < max(min_ratio * largest, min_snr * noise):
            reasons.append("weak")
        elif not first <= u <= last:
            reasons.append("out_of_range")
        elif w < min_width * pulse_fwhm:
            reasons.append("too_narrow")
        elif w > max_width * pulse_fwhm:
            reasons.append("too_wide")
        else:
            reasons.append("")
    kept = [k for k, r in enumerate(reasons) if r == ""]
    previous = None
    for k in kept:
        if previous is not None and position[k] - position[previous] < min_separation * pulse_fwhm:
            # the earlier stays unless it is below first_echo_ratio x the later
            dropped = previous if first_echo_ratio * amplitude[k] > amplitude[previous] else k
            reasons[dropped] = "too_close"
            previous = k if dropped == previous else previous
        else:
            previous = k
    return reasons


def _inflection_distance(residual, peak, step):
    d2 = lambda i: residual[i - 1] - 2 * residual[i] + residual[i + 1]  # noqa: E731
    prev = d2(peak) if 0 < peak < len(residual) - 1 else -1.0
    i = peak + step
    while 0 < i < len(residual) - 1:
        if d2(i) >= 0:
            frac = prev / (prev - d2(i)) if prev < 0 else 1.0
            return abs(i - peak) - 1 + frac
        prev = d2(i)
        i += step
    return -1.0


def progressive_echoes(smoothed, background, threshold, max_echoes, fallback_sigma, floor_ratio=0.0):
    """Peel Gaussian echoes off the largest remaining peak above its sample's threshold (all samples valid;
    sigma from the inflection points, one side doubling the other, else the half-height width); once the
    largest peak left is under floor_ratio x the first echo, only peaks in an echo's return (a run of samples
    above the threshold before peeling) or within one FWHM of an echo remain."""
    residual = np.asarray(smoothed, dtype=float) - background
    t = np.arange(residual.size)
    above = residual > threshold
    run = np.cumsum(np.r_[above[0], above[1:] & ~above[:-1]]) * above  # 1, 2, ... on each run, 0 elsewhere
    reach = 2.0 * SQRT_2LN2 * fallback_sigma
    allowed = np.ones(residual.size, bool)
    echoes, echo_runs = [], []
    while len(echoes) < max_echoes:
        candidates = np.flatnonzero((residual > threshold) & allowed)
        if candidates.size == 0:
            break
        peak = int(candidates[np.argmax(residual[candidates])])
        if echoes and residual[peak] < floor_ratio * echoes[0][0]:
            near = np.isin(run, [r for r in echo_runs if r > 0])
            for _, centre, _ in echoes:
                near |= np.abs(t - centre) <= reach
            if not near[peak]:
                allowed &= near
                continue
        echo_runs.append(run[peak])
        left, right = _inflection_distance(residual, peak, -1), _inflection_distance(residual, peak, 1)
        if left > 0 and right > 0:
            sigma = 0.5 * (left + right)
        elif max(left, right) > 0:
            sigma = max(left, right)
        else:
            sigma = fallback_sigma  # the kernel tries the half-height width first; tests avoid that case
        sigma = max(sigma, 0.5)
        height = residual[peak]
        echoes.append((height, float(peak), sigma))
        residual = residual - height * np.exp(-0.5 * ((t - peak) / sigma) ** 2)
    return echoes


def chi2_without_echo(x, k, times, raw, sigma, lower, upper):
    """chi^2 of the least-squares refit (SciPy, from x) of individual x without echo k, and with it."""
    from scipy.optimize import least_squares

    def fit(x0, lo, hi):
        free = lo < hi
        def residual(v):
            full = np.where(free, 0.0, x0)
            full[free] = v
            return (model_of_individual(full, times) - raw) / sigma
        sol = least_squares(residual, np.clip(x0, lo, hi)[free], bounds=(lo[free], hi[free]), xtol=1e-12,
                            ftol=1e-12)
        return float(np.sum(sol.fun ** 2))

    keep = np.ones(x.size, bool)
    keep[1 + 4 * k:5 + 4 * k] = False
    return fit(x[keep], lower[keep], upper[keep]), fit(x, lower, upper)


def response_echo(times_ps: np.ndarray, values: np.ndarray, spacing_ps: float, amplitude: float, position: float,
                  s: float, t: np.ndarray) -> np.ndarray:
    """An echo of a measured response, from its definition: the response (ps grid) convolved with the
    Gaussian whose broadening gives an FWHM of s x 2 sqrt(2 ln 2) samples (found by bisection), peak scaled
    to `amplitude`, the centroid of the response's lobe above 5% of its peak at `position` (samples), on a
    1/64-sample grid."""
    step = 1.0 / 64.0
    peak = int(np.argmax(values))
    lo_, hi_ = peak, peak
    while lo_ > 0 and values[lo_ - 1] > 0.05 * values[peak]:
        lo_ -= 1
    while hi_ < values.size - 1 and values[hi_ + 1] > 0.05 * values[peak]:
        hi_ += 1
    lobe = values[lo_:hi_ + 1]
    times_ps = times_ps - np.sum(times_ps[lo_:hi_ + 1] * lobe) / np.sum(lobe)
    grid = np.arange((times_ps[0] / spacing_ps) - 6 * s - 1, (times_ps[-1] / spacing_ps) + 6 * s + 1, step)
    base = np.interp(grid, times_ps / spacing_ps, values, left=0.0, right=0.0)

    def broadened(b: float) -> np.ndarray:
        if b < 1e-6:
            return base
        half = int(np.ceil(6 * b / step))
        kernel = np.exp(-0.5 * (np.arange(-half, half + 1) * step / b) ** 2)
        return np.convolve(base, kernel / kernel.sum(), mode="same")

    def width(y: np.ndarray) -> float:
        above = grid[y >= 0.5 * y.max()]
        return above[-1] - above[0]

    target = s * 2.0 * SQRT_2LN2
    lo, hi = 0.0, 3.0 * s
    if width(base) < target:
        for _ in range(50):
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if width(broadened(mid)) < target else (lo, mid)
    y = broadened(0.5 * (lo + hi) if width(base) < target else 0.0)
    return amplitude * np.interp(np.asarray(t, float) - position, grid, y / y.max(), left=0.0, right=0.0)


def model_jacobian(x: np.ndarray, t: np.ndarray) -> np.ndarray:
    """d model_of_individual / dx (len(t) x len(x)) from the derivatives of b + A exp(-ln2 z**p),
    z = |t - u| / h, h = s sqrt(2 ln 2), p = alpha**2."""
    t = np.asarray(t, dtype=float)
    jac = np.zeros((t.size, len(x)))
    jac[:, 0] = 1.0
    ln2 = np.log(2.0)
    for k, (a, u, s, alpha) in enumerate(np.asarray(x[1:], dtype=float).reshape(-1, 4)):
        h, p = s * SQRT_2LN2, alpha * alpha
        z = np.abs(t - u) / h
        e = np.exp(-ln2 * z ** p)
        log_z = np.log(np.where(z > 0, z, 1.0))  # z**p ln z -> 0 at z = 0
        jac[:, 1 + 4 * k] = e
        jac[:, 2 + 4 * k] = a * e * ln2 * p * z ** (p - 1) * np.sign(t - u) / h
        jac[:, 3 + 4 * k] = a * e * ln2 * p * z ** p / s
        jac[:, 4 + 4 * k] = -2.0 * alpha * a * e * ln2 * z ** p * log_z
    return jac


def least_squares_fit(x0, t, y, lower, upper, method: str = "lm") -> tuple[np.ndarray, float]:
    """SciPy's least squares on sum (model_of_individual(x, t) - y)**2 from x0, the parameters with lower ==
    upper held: (x, sum of squares). `lm` (MINPACK) ignores the bounds: use it where the optimum is inside them."""
    from scipy.optimize import least_squares

    x0, lower, upper = (np.asarray(v, dtype=float) for v in (x0, lower, upper))
    free = lower < upper

    def full(v):
        x = x0.copy()
        x[free] = v
        return x

    bounds = (-np.inf, np.inf) if method == "lm" else (lower[free], upper[free])
    sol = least_squares(lambda v: model_of_individual(full(v), t) - y, np.clip(x0, lower, upper)[free],
                        jac=lambda v: model_jacobian(full(v), t)[:, free], method=method, bounds=bounds,
                        xtol=1e-15, ftol=1e-15, gtol=1e-15, max_nfev=10000)
    return full(sol.x), float(np.sum(sol.fun ** 2))


def lbfgs_fit(x0, t, y, lower, upper) -> tuple[np.ndarray, float]:
    """SciPy's L-BFGS-B on sum (model_of_individual(x, t) - y)**2 inside [lower, upper] from x0, its gradient
    2 J^T r: (x, sum of squares)."""
    from scipy.optimize import minimize

    def cost(x):
        r = model_of_individual(x, t) - y
        return float(r @ r), 2.0 * model_jacobian(x, t).T @ r

    x0, lower, upper = (np.asarray(v, dtype=float) for v in (x0, lower, upper))
    sol = minimize(cost, np.clip(x0, lower, upper), jac=True, method="L-BFGS-B", bounds=list(zip(lower, upper)),
                   options=dict(ftol=1e-15, gtol=1e-12, maxiter=10000, maxcor=20))
    return sol.x, float(sol.fun)


def patent_peaks(smoothed, background, threshold, first, last, window: int = 5):
    """The patent's peak search on all-valid samples: a sample above threshold that is the largest within
    +-window (the first of a flat top), with its ranges [(peak, A_hi, u_lo, u_hi, s_hi)]: A up to the peak's
    height, u within +-window, sigma up to 3 (p2 - p1) / 2 between the inflection points (3 |p - peak| with one;
    the kernel's half-height fallback is left out: tests avoid it)."""
    residual = np.asarray(smoothed, dtype=float) - background
    found = []
    for i in np.flatnonzero(residual > threshold):
        around = residual[max(0, i - window):i + window + 1]
        before = residual[max(0, i - window):i]
        if around.max() > residual[i] or (before == residual[i]).any():
            continue
        left, right = _inflection_distance(residual, i, -1), _inflection_distance(residual, i, 1)
        if left > 0 and right > 0:
            s_hi = 3.0 * (left + right) / 2.0
        else:
            s_hi = 3.0 * max(left, right)
        found.append((int(i), residual[i], max(first, i - window), min(last, i + window), s_hi))
    return found


def gaussian_individual(x: np.ndarray) -> np.ndarray:
    """[b, (A, u, sigma) per Gaussian echo] -> [b, (A, u, s, sqrt 2) per echo] (a Gaussian's s is its sigma)."""
    echoes = np.asarray(x[1:], dtype=float).reshape(-1, 3)
    return np.concatenate([[x[0]], np.column_stack([echoes, np.full(len(echoes), np.sqrt(2.0))]).ravel()])
