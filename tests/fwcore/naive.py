"""Slow, obviously-correct references for the numba kernels (the stumpy habit)."""

from __future__ import annotations

import numpy as np

from fwcore.model import SQRT_2LN2, sigma_from_equivalent, waveform_model
from fwcore.rng import SplitMix64


def model_of_individual(x: np.ndarray, t: np.ndarray) -> np.ndarray:
    """[b, (A, u, s, alpha)...] -> model, through Chauve's sigma, in float64."""
    echoes = x[1:].reshape(-1, 4)
    return waveform_model(t, x[0], echoes[:, 0], echoes[:, 1],
                          sigma_from_equivalent(echoes[:, 2], echoes[:, 3]), echoes[:, 3])


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


__all__ = ["SQRT_2LN2", "model_of_individual", "gaussian_smooth", "mde_generation"]
