"""One typed configuration for the decomposition, passed down to every stage.

Strings from the command line or a TOML file become enums here, once, and
every value is validated up front with an error that says how to fix it.
"""

from __future__ import annotations

import dataclasses
import enum
import math
import operator
import tomllib
from pathlib import Path
from typing import Any, NamedTuple, get_type_hints


class Optimizer(str, enum.Enum):
    NONE = "none"  # the initial estimate as is
    LM = "lm"  # Levenberg-Marquardt from the initial estimate
    LBFGS = "lbfgs"  # projected L-BFGS from the initial estimate
    GA = "ga"  # real-coded genetic algorithm
    PSO = "pso"  # particle swarm
    DE = "de"  # differential evolution, the method's Eq. 4
    MDE = "mde"  # modified DE with chaotic scale factors
    MDE_LM = "mde-lm"  # MDE, then LM polish of its best individual
    GA_ITERATIVE = "ga-iterative"  # the patent: binary GA, echoes added until R^2 is reached
    LM_MDE = "lm-mde"  # LM; MDE around it where LM does not settle and its fit fails the noise model (the default)
    GOLD = "gold"  # Gold deconvolution with the system response, echoes from the recovered profile
    RICHARDSON_LUCY = "richardson-lucy"  # Richardson-Lucy deconvolution, likewise


# The catalogue: each optimizer's kernel code and kind (the kernels: fwcore.optimizers).
(OPT_NONE, OPT_DE, OPT_MDE, OPT_GA, OPT_PSO, OPT_LM, OPT_LBFGS, OPT_MDE_LM, OPT_GA_ITERATIVE, OPT_LM_MDE, OPT_GOLD,
 OPT_RICHARDSON_LUCY) = range(12)
# Per-waveform messages (records.MESSAGES spells them out).
MSG_NO_ECHOES, MSG_CONVERGED, MSG_MAX_GENERATIONS, MSG_MAX_ITERATIONS, MSG_NOT_OPTIMIZED = range(5)


@dataclasses.dataclass(frozen=True)
class OptimizerSpec:
    """A catalogue entry: its kernel code, and what kind of search it is."""

    code: int
    population: bool  # a population of individuals on Eq. 9, or not
    local: bool  # ends with (or is) a least-squares local optimizer on the valid samples
    description: str
    own_echoes: bool = False  # finds its own echoes (not the initial estimate's); no selection after it


OPTIMIZERS: dict[Optimizer, OptimizerSpec] = {
    Optimizer.NONE: OptimizerSpec(OPT_NONE, False, False, "the initial estimate as is"),
    Optimizer.DE: OptimizerSpec(OPT_DE, True, False, "differential evolution, DE/rand/1 (the method's Eq. 4)"),
    Optimizer.MDE: OptimizerSpec(OPT_MDE, True, False, "modified DE with chaotic scale factors"),
    Optimizer.GA: OptimizerSpec(OPT_GA, True, False, "real-coded genetic algorithm"),
    Optimizer.PSO: OptimizerSpec(OPT_PSO, True, False, "global-best particle swarm"),
    Optimizer.LM: OptimizerSpec(OPT_LM, False, True, "Levenberg-Marquardt from the initial estimate"),
    Optimizer.LBFGS: OptimizerSpec(OPT_LBFGS, False, True, "projected L-BFGS from the initial estimate"),
    Optimizer.MDE_LM: OptimizerSpec(OPT_MDE_LM, True, True, "MDE, then an LM polish of its best individual"),
    Optimizer.GA_ITERATIVE: OptimizerSpec(OPT_GA_ITERATIVE, False, True,
                                          "the patent's binary GA, adding echoes until R^2 is reached", True),
    Optimizer.LM_MDE: OptimizerSpec(OPT_LM_MDE, True, True,
                                    "LM; where it does not converge and its fit fails the noise model's chi^2 "
                                    "test, MDE around it, polished by LM, kept when clearly better"),
    Optimizer.GOLD: OptimizerSpec(OPT_GOLD, False, False, "Gold deconvolution with the system response, echoes "
                                  "from the recovered profile's lobes", True),
    Optimizer.RICHARDSON_LUCY: OptimizerSpec(OPT_RICHARDSON_LUCY, False, False, "Richardson-Lucy deconvolution "
                                             "with the system response, echoes from the profile's lobes", True),
}



class Model(str, enum.Enum):
    SYSTEM = "system"  # the instrument's measured response, shifted, scaled and broadened (fwcore.instrument)
    GENERALIZED = "generalized"  # the method's generalized Gaussian
    GAUSSIAN = "gaussian"
    # per file, the one of system and generalized whose echoes predict its held-out samples better
    # (fwcore.instrument.measure.choose_system_pulse); waveforms with no file around them get the generalized Gaussian
    AUTO = "auto"


class FitTarget(str, enum.Enum):
    DENOISED = "denoised"
    RAW = "raw"


class NoiseEstimator(str, enum.Enum):
    # sqrt(mean((raw - smoothed)**2)): the method's formula, which keeps only the part of white
    # noise that the light smoothing removes (about 0.4 of it at the default smoothing)
    RESIDUAL = "residual"
    # the median absolute (raw - smoothed), divided by the filter's known attenuation of white noise
    # per sample, sqrt(1 - 2 w_ii + sum_j w_ij**2): unbiased for white noise and robust to the echoes
    ROBUST = "robust"


@dataclasses.dataclass(frozen=True)
class DecompositionConfig:
    """Every method parameter of a decomposition run."""

    optimizer: Optimizer = Optimizer.LM_MDE
    model: Model = Model.AUTO
    # Evolution: population NP and generations G (the MDE paper: 60 and 80); with tol > 0,
    # G is the most a waveform may take.
    population: int = 60
    generations: int = 200
    crossover_rate: float = 0.9  # CR
    # MDE's chaotic scale factors: t seeds, k logistic-map iterations, range [a, b].
    chaos_seeds: int = 1  # t
    chaos_iterations: int = 5  # k
    scale_min: float = 0.2  # a
    scale_max: float = 1.0  # b
    # Plain DE's fixed scale factor (the paper's Eq. 4).
    de_scale_factor: float = 0.5
    # Write each DE/MDE winner back at once (asynchronous DE) instead of once per generation.
    immediate: bool = False
    # Half size of the box around the initial estimate that seeds the population,
    # as a fraction of each parameter's bound range.
    init_spread: float = 0.25
    # Denoising: Gaussian filter sigma = smoothing_factor * system pulse sigma,
    # unless smoothing_sigma_ps is given (0 turns smoothing off).
    smoothing_factor: float = 0.25
    smoothing_sigma_ps: float | None = None
    fit_target: FitTarget = FitTarget.DENOISED
    # With the denoised target: where the final fit's chi^2 per degree of freedom on the raw samples,
    # under the noise model, exceeds raw_polish_gate, LM refits the raw samples from it (the smoothing's
    # bias on steep, high-count rises; NEON raw error 254 -> 239 DN, Leica and the flight unchanged).
    raw_polish: bool = True
    raw_polish_gate: float = 1.5
    # Initial estimate: an echo must rise noise_threshold x the noise at its sample above background.
    noise_threshold: float = 3.0
    noise_estimator: NoiseEstimator = NoiseEstimator.ROBUST
    # sigma_noise is floored here (digitizer units): the quantisation of an integer digitizer is
    # uniform noise of 1/sqrt(12) DN whatever the analogue noise below it.
    min_noise_sigma: float = 1.0 / math.sqrt(12.0)
    # The noise model of a sample with signal s above background (digitizer units):
    # variance = sigma_noise**2 + g s + (shape_tolerance s)**2. g (Poisson-like shot noise) is
    # fitted per waveform to the residual of the optimizer's fit; shape_tolerance, how far the
    # system's pulse may depart from a generalized Gaussian without being another echo, is the file's
    # (fwcore.instrument.pulse.SystemPulse). A shape tolerance of 0 and signal_dependent_noise=False give
    # the method's constant noise.
    signal_dependent_noise: bool = True
    max_echoes: int = 12
    alpha_min: float = 1.0
    alpha_max: float = 2.6
    # Filter of spurious echoes (the method's section 1.2). The paper's values are 0.2, -, 1.0, 1.0, 3.0.
    # The paper's 20% drops weak ground returns under canopy (measured on the Leica system returns);
    # the SNR floor is low because the BIC selection already decides which echoes the data supports:
    # on the simulated flight a floor of 6 sigma loses half the true echoes between 5 and 10 sigma
    # (recall 0.88), 2 sigma keeps them at the same precision (README, "Presets").
    min_amplitude_ratio: float = 0.05
    min_snr: float = 2.0  # amplitude below min_snr x sigma_noise is weak too
    min_separation_factor: float = 1.0  # x system pulse FWHM
    min_width_factor: float = 0.5  # x system pulse FWHM
    max_width_factor: float = 3.0  # x system pulse FWHM
    # Of two echoes closer than the separation (one unresolved return), the earlier is kept when it is at
    # least this share of the later's amplitude; otherwise the weaker. 1 (the method's rule): the weaker
    # goes. 0.35 reports an unresolved return at its first surface, as the Leica system's detector does
    # (its returns recovered 0.973 -> 0.980), but costs the simulated flight 0.7 points of recall and
    # 0.9 of precision (README, "Decisions where the method is silent").
    first_echo_ratio: float = 1.0
    # Model-order selection after the optimizer: drop the echoes the filter flags when the raw
    # samples do not need them, add one where the residual holds an echo, each by the Bayesian
    # information criterion under the noise model, with warm-started LM refits.
    select_echoes: bool = True
    max_added_echoes: int = 2  # echoes the selection may add per waveform
    lm_iterations: int = 50  # LM iterations (L-BFGS gets 4x as many)
    # LM stops when an accepted step lowers the weighted sum of squares (chi^2) by less than this share of
    # it: 1e-4 of a chi^2 of m samples is a few hundredths, far below what the data tell apart. 1e-6 kept
    # the tabulated model's LM creeping over its table's kinks (RIEGL: 11% of fits ran out of iterations),
    # for the same echoes: Leica's returns, RIEGL's ghosts and the flights alike, NEON's raw error within 0.2%.
    lm_tolerance: float = 1e-4
    # Population methods stop when the spread of the population's fitness is small
    # (SciPy's rule: std(fitness) <= atol + tol |mean(fitness)|), at most after `generations`.
    # tol = atol = 0 runs every generation (the paper's fixed G).
    tol: float = 0.01
    atol: float = 0.0
    # With tol > 0, atol grows by noise_tol x the spread that the noise alone gives Eq. 9's fitness,
    # sigma_noise sqrt(m (1 - 2 / pi)): a population that agrees to within the noise has converged
    # (RIEGL, system model: MDE 2.7x faster, the same echoes). White noise's figure: the default fits the
    # denoised samples, whose correlated noise spreads the fitness less, so this stops a little early.
    noise_tol: float = 1.0
    # With tol > 0, DE and MDE also stop when their best individual improved by no more than that atol over
    # the last stall_generations generations (pymoo's ftol over a period): a search whose best moves by
    # less than the noise's share of the fitness has found what it will find. 0: off. RIEGL (system model):
    # two waveforms' wandering baselines kept lm-mde's MDE searching 142-200 generations for no better fit,
    # 40% of the default's time; the same raw error on RIEGL and NEON with 10, 20 or no stall rule.
    stall_generations: int = 20
    # GA: probability that a parameter mutates (the crossover rate is CR above).
    ga_mutation_rate: float = 0.1
    # ga-iterative (the patent): add echoes while R^2 is below this; generations per GA fit.
    ga_iterative_r2: float = 0.98
    ga_iterative_generations: int = 1000
    # gold, richardson-lucy: multiplicative iterations of the deconvolution
    deconvolution_iterations: int = 200
    # lm-mde: MDE searches where LM did not converge in lm_iterations and its fit's chi^2 per degree of
    # freedom on the raw samples, under the noise model with its Poisson-like term, exceeds this. Where LM
    # converged, a failing fit is the model's misfit, which MDE ends in too: after a converged LM it
    # improved the raw error by more than 1% on 2 of 1,037 waveforms (NEON, Leica, RIEGL; docs/decisions.md).
    mde_gate: float = 2.0
    seed: int = 0

    def __post_init__(self) -> None:
        for name, kind in (("optimizer", Optimizer), ("model", Model), ("fit_target", FitTarget),
                           ("noise_estimator", NoiseEstimator)):
            value = getattr(self, name)
            if not isinstance(value, kind):
                try:
                    object.__setattr__(self, name, kind(value))
                except ValueError:
                    allowed = ", ".join(m.value for m in kind)
                    raise ValueError(f"{name} must be one of {allowed}, not {value!r}") from None
        self._check(self.population >= 5, "population (NP) must be at least 5: MDE draws 4 distinct partners")
        self._check(self.generations >= 0, "generations (G) must be >= 0")
        self._check(0.0 <= self.crossover_rate <= 1.0, "crossover_rate (CR) must lie in [0, 1]")
        self._check(self.chaos_seeds >= 1 and self.chaos_iterations >= 1,
                    "chaos_seeds (t) and chaos_iterations (k) must be >= 1")
        self._check(0.0 <= self.scale_min < self.scale_max,
                    "the scale factor range [scale_min, scale_max] must satisfy 0 <= a < b")
        self._check(self.max_echoes >= 1, "max_echoes must be >= 1")
        self._check(0.5 <= self.alpha_min <= math.sqrt(2) <= self.alpha_max <= 4.0,
                    "need 0.5 <= alpha_min <= sqrt(2) <= alpha_max <= 4")
        self._check(self.smoothing_factor >= 0 and (self.smoothing_sigma_ps or 0) >= 0,
                    "smoothing must be >= 0")
        self._check(self.noise_threshold > 0, "noise_threshold must be positive")
        self._check(self.min_noise_sigma >= 0, "min_noise_sigma must be >= 0")
        self._check(0 <= self.min_width_factor < self.max_width_factor and self.max_width_factor > 1,
                    "need 0 <= min_width_factor < max_width_factor and max_width_factor > 1 (x the pulse FWHM)")
        self._check(self.first_echo_ratio >= 0, "first_echo_ratio must be >= 0")
        self._check(self.raw_polish_gate >= 0, "raw_polish_gate must be >= 0")
        self._check(self.max_added_echoes >= 0, "max_added_echoes must be >= 0")
        self._check(self.tol >= 0 and self.atol >= 0 and self.noise_tol >= 0, "tol, atol and noise_tol must be >= 0")
        self._check(self.stall_generations >= 0, "stall_generations must be >= 0")
        self._check(self.lm_iterations >= 1, "lm_iterations must be >= 1")
        self._check(0 < self.lm_tolerance < 1, "lm_tolerance must lie in (0, 1)")
        self._check(0.0 <= self.ga_mutation_rate <= 1.0, "ga_mutation_rate must lie in [0, 1]")
        self._check(0.0 < self.ga_iterative_r2 <= 1.0, "ga_iterative_r2 must lie in (0, 1]")
        self._check(self.ga_iterative_generations >= 1, "ga_iterative_generations must be >= 1")
        self._check(self.deconvolution_iterations >= 1, "deconvolution_iterations must be >= 1")
        self._check(0 <= self.init_spread <= 1, "init_spread must lie in [0, 1]")
        self._check(self.mde_gate >= 0, "mde_gate must be >= 0")

    @staticmethod
    def _check(ok: bool, message: str) -> None:
        if not ok:
            raise ValueError(f"invalid decomposition configuration: {message}")

    @property
    def chaos_candidates(self) -> int:
        """k x t: candidate mutants tried per MDE mutation."""
        return self.chaos_seeds * self.chaos_iterations

    def kernel_params(self, model: Model, shape_tolerance: float) -> "KernelParams":
        """The settings the numba kernels read, as one typed tuple (numba takes NamedTuples), with what the file's
        pulse says (fwcore.instrument.pulse.SystemPulse): its echo model and shape tolerance."""
        return KernelParams.typed(
            method=OPTIMIZERS[self.optimizer].code, own_echoes=OPTIMIZERS[self.optimizer].own_echoes,
            deconvolution_iterations=self.deconvolution_iterations,
            gaussian=model in (Model.SYSTEM, Model.GAUSSIAN),
            fit_denoised=self.fit_target is FitTarget.DENOISED,
            robust_noise=self.noise_estimator is NoiseEstimator.ROBUST,
            population=self.population, generations=self.generations, crossover_rate=self.crossover_rate,
            chaos_seeds=self.chaos_seeds, chaos_iterations=self.chaos_iterations, scale_min=self.scale_min,
            scale_max=self.scale_max, de_scale_factor=self.de_scale_factor, immediate=self.immediate,
            init_spread=self.init_spread,
            tol=self.tol, atol=self.atol, noise_tol=self.noise_tol, stall_generations=self.stall_generations,
            noise_threshold=self.noise_threshold,
            min_noise_sigma=self.min_noise_sigma, signal_dependent_noise=self.signal_dependent_noise,
            shape_tolerance=shape_tolerance, max_echoes=self.max_echoes, alpha_min=self.alpha_min,
            alpha_max=self.alpha_max, min_snr=self.min_snr, min_amplitude_ratio=self.min_amplitude_ratio,
            min_separation_factor=self.min_separation_factor, min_width_factor=self.min_width_factor,
            max_width_factor=self.max_width_factor, first_echo_ratio=self.first_echo_ratio,
            raw_polish=self.raw_polish, raw_polish_gate=self.raw_polish_gate,
            select_echoes=self.select_echoes,
            max_added_echoes=self.max_added_echoes, lm_iterations=self.lm_iterations,
            lm_tolerance=self.lm_tolerance,
            ga_mutation_rate=self.ga_mutation_rate, ga_iterative_r2=self.ga_iterative_r2,
            ga_iterative_generations=self.ga_iterative_generations, mde_gate=self.mde_gate)

    def replace(self, **changes: Any) -> "DecompositionConfig":
        return dataclasses.replace(self, **changes)

    def changes(self) -> dict[str, Any]:
        """The settings that differ from the defaults (what a TOML file or preset set)."""
        default = DecompositionConfig()
        return {f.name: getattr(self, f.name) for f in dataclasses.fields(self)
                if getattr(self, f.name) != getattr(default, f.name)}

    def to_dict(self) -> dict[str, Any]:
        return {f.name: (v.value if isinstance(v, enum.Enum) else v)
                for f in dataclasses.fields(self) for v in [getattr(self, f.name)]}

    @classmethod
    def from_dict(cls, values: dict[str, Any]) -> "DecompositionConfig":
        known = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(values) - known)
        if unknown:
            raise ValueError(f"unknown decomposition settings {unknown}; known: {sorted(known)}")
        return cls(**values)

    @classmethod
    def from_toml(cls, path: str | Path) -> "DecompositionConfig":
        """Load the [decomposition] table of a TOML file (or its top level)."""
        with open(path, "rb") as f:
            data = tomllib.load(f)
        try:
            return cls.from_dict(data.get("decomposition", data))
        except (TypeError, ValueError) as err:
            raise ValueError(f"{path}: {err}") from None


class KernelParams(NamedTuple):
    """DecompositionConfig as the kernels see it: enums as codes and flags, nothing else."""

    method: int
    own_echoes: bool
    deconvolution_iterations: int
    gaussian: bool
    fit_denoised: bool
    robust_noise: bool
    population: int
    generations: int
    crossover_rate: float
    chaos_seeds: int
    chaos_iterations: int
    scale_min: float
    scale_max: float
    de_scale_factor: float
    immediate: bool
    init_spread: float
    tol: float
    atol: float
    noise_tol: float
    stall_generations: int
    noise_threshold: float
    min_noise_sigma: float
    signal_dependent_noise: bool
    shape_tolerance: float
    max_echoes: int
    alpha_min: float
    alpha_max: float
    min_snr: float
    min_amplitude_ratio: float
    min_separation_factor: float
    min_width_factor: float
    max_width_factor: float
    first_echo_ratio: float
    raw_polish: bool
    raw_polish_gate: float
    select_echoes: bool
    max_added_echoes: int
    lm_iterations: int
    lm_tolerance: float
    ga_mutation_rate: float
    ga_iterative_r2: float
    ga_iterative_generations: int
    mde_gate: float

    @classmethod
    def typed(cls, **values: Any) -> "KernelParams":
        """Each value as its field's type: numba compiles every kernel afresh for each tuple of argument
        types, so min_snr=8 (an int from JSON or TOML) beside min_snr=8.0 would cost a second full compile."""
        cast = {float: float, int: operator.index, bool: bool}  # index: an int setting of 2.5 stays an error
        kinds = get_type_hints(cls)
        return cls(**{name: cast[kinds[name]](values[name]) for name in cls._fields})


# Named configurations (README, "Presets"): the defaults are the best we know.
# "paper": the MDE method exactly as published: its generalized Gaussian, its noise formula and constant
# noise, its filter (20% of the largest amplitude, widths from 1x to 3x the pulse), MDE for a fixed G = 80, no
# polish (neither LM's nor the raw one), no selection; its model taken as exact (a shape tolerance of 0:
# fwcore.instrument.pulse.PRESET_OVERRIDES). "fast": LM alone from the initial estimate,
# fewer and looser iterations, with the default's selection.
PRESETS: dict[str, dict[str, Any]] = {
    "paper": {"optimizer": Optimizer.MDE, "model": Model.GENERALIZED, "generations": 80, "tol": 0.0, "atol": 0.0,
              "noise_estimator": NoiseEstimator.RESIDUAL, "min_noise_sigma": 1.0,
              "signal_dependent_noise": False, "select_echoes": False,
              "min_amplitude_ratio": 0.2, "min_snr": 0.0, "min_width_factor": 1.0, "raw_polish": False},
    "fast": {"optimizer": Optimizer.LM, "lm_iterations": 20},
}
