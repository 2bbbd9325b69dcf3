"""One typed configuration for the decomposition, passed down to every stage.

Strings from the command line or a TOML file become enums here, once, and
every value is validated up front with an error that says how to fix it.
"""

from __future__ import annotations

import dataclasses
import enum
import math
import tomllib
from pathlib import Path
from typing import Any


class Optimizer(str, enum.Enum):
    NONE = "none"  # the initial estimate as is
    LM = "lm"  # Levenberg-Marquardt from the initial estimate
    LBFGS = "lbfgs"  # projected L-BFGS from the initial estimate
    GA = "ga"  # real-coded genetic algorithm
    PSO = "pso"  # particle swarm
    DE = "de"  # differential evolution, the method's Eq. 4
    MDE = "mde"  # modified DE with chaotic scale factors (the default)
    MDE_LM = "mde-lm"  # MDE, then LM polish of its best individual
    GA_ITERATIVE = "ga-iterative"  # the patent: binary GA, echoes added until R^2 is reached


class Model(str, enum.Enum):
    GENERALIZED = "generalized"
    GAUSSIAN = "gaussian"


class FitTarget(str, enum.Enum):
    DENOISED = "denoised"
    RAW = "raw"


@dataclasses.dataclass(frozen=True)
class DecompositionConfig:
    """Every method parameter of a decomposition run."""

    optimizer: Optimizer = Optimizer.MDE
    model: Model = Model.GENERALIZED
    # Evolution: population NP and generations G (the MDE paper: 60 and 80).
    population: int = 60
    generations: int = 80
    crossover_rate: float = 0.9  # CR
    # MDE's chaotic scale factors: t seeds, k logistic-map iterations, range [a, b].
    chaos_seeds: int = 1  # t
    chaos_iterations: int = 5  # k
    scale_min: float = 0.2  # a
    scale_max: float = 1.0  # b
    # Plain DE's fixed scale factor (the paper's Eq. 4).
    de_scale_factor: float = 0.5
    # Half size of the box around the initial estimate that seeds the population,
    # as a fraction of each parameter's bound range.
    init_spread: float = 0.25
    # System: the emitted pulse's FWHM in ps; None lets the caller derive it
    # (from outgoing pulses) or falls back to `default_pulse_fwhm_ps`.
    system_pulse_fwhm_ps: float | None = None
    default_pulse_fwhm_ps: float = 4000.0
    # Denoising: Gaussian filter sigma = smoothing_factor * system pulse sigma,
    # unless smoothing_sigma_ps is given (0 turns smoothing off).
    smoothing_factor: float = 0.25
    smoothing_sigma_ps: float | None = None
    fit_target: FitTarget = FitTarget.DENOISED
    # Initial estimate: an echo must rise noise_threshold * sigma_noise above background.
    noise_threshold: float = 3.0
    # sigma_noise is floored here (digitizer units): integer samples with little smoothing
    # otherwise give sigma_noise = 0 and every quantisation ripple becomes an echo.
    min_noise_sigma: float = 1.0
    max_echoes: int = 12
    alpha_min: float = 1.0
    alpha_max: float = 2.6
    # Filter of spurious echoes (the method's section 1.2). The paper's values are 0.2, -, 1.0, 1.0, 3.0;
    # these defaults were measured against the Leica system returns (README): the paper's 20% drops
    # weak ground returns under canopy, and an SNR floor removes the few-count bumps instead.
    min_amplitude_ratio: float = 0.05
    min_snr: float = 4.0  # amplitude below min_snr x sigma_noise is weak too
    min_separation_factor: float = 1.0  # x system pulse FWHM
    min_width_factor: float = 0.5  # x system pulse FWHM
    max_width_factor: float = 3.0  # x system pulse FWHM
    # After the optimizer: drop spurious echoes that the data does not need (BIC, LM refit);
    # lm_iterations bounds each Levenberg-Marquardt refit.
    prune_echoes: bool = False
    lm_iterations: int = 50  # LM iterations (L-BFGS gets 4x as many)
    # GA: probability that a parameter mutates (the crossover rate is CR above).
    ga_mutation_rate: float = 0.1
    # ga-iterative (the patent): add echoes while R^2 is below this; generations per GA fit.
    ga_iterative_r2: float = 0.98
    ga_iterative_generations: int = 1000
    seed: int = 0

    def __post_init__(self) -> None:
        for name, kind in (("optimizer", Optimizer), ("model", Model), ("fit_target", FitTarget)):
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
        self._check(self.default_pulse_fwhm_ps > 0 and (self.system_pulse_fwhm_ps is None
                                                         or self.system_pulse_fwhm_ps > 0),
                    f"system pulse FWHM must be positive (ps), not {self.system_pulse_fwhm_ps}")
        self._check(self.smoothing_factor >= 0 and (self.smoothing_sigma_ps or 0) >= 0,
                    "smoothing must be >= 0")
        self._check(self.noise_threshold > 0, "noise_threshold must be positive")
        self._check(self.min_noise_sigma >= 0, "min_noise_sigma must be >= 0")
        self._check(self.lm_iterations >= 1, "lm_iterations must be >= 1")
        self._check(0.0 <= self.ga_mutation_rate <= 1.0, "ga_mutation_rate must lie in [0, 1]")
        self._check(0.0 < self.ga_iterative_r2 <= 1.0, "ga_iterative_r2 must lie in (0, 1]")
        self._check(self.ga_iterative_generations >= 1, "ga_iterative_generations must be >= 1")
        self._check(0 <= self.init_spread <= 1, "init_spread must lie in [0, 1]")

    @staticmethod
    def _check(ok: bool, message: str) -> None:
        if not ok:
            raise ValueError(f"invalid decomposition configuration: {message}")

    @property
    def chaos_candidates(self) -> int:
        """k x t: candidate mutants tried per MDE mutation."""
        return self.chaos_seeds * self.chaos_iterations

    def pulse_fwhm_ps(self) -> float:
        return self.default_pulse_fwhm_ps if self.system_pulse_fwhm_ps is None else self.system_pulse_fwhm_ps

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


# Named configurations. "paper": MDE at the method's settings (the defaults). "fast": chosen by
# the budget study of `fwl compare --budget` as the highest throughput whose mean fit error stays
# within 5% of "paper" on the bundled NEON and Leica samples (README, "The evaluation budget").
# "accurate": MDE, then the spurious echoes the data does not need are pruned: against the truth of
# simulated flights it cuts the range RMSE about threefold (README, "Accuracy against truth").
PRESETS: dict[str, dict[str, Any]] = {
    "paper": {},
    "fast": {"optimizer": Optimizer.LM, "lm_iterations": 20},
    "accurate": {"prune_echoes": True},
}
