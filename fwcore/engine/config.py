"""One typed configuration for the decomposition, passed down to every stage.

Strings from the command line or a TOML file become enums here, once, and
every value is validated up front with an error that says how to fix it.
Each setting is declared once, as a field whose metadata (`setting`) says its
command-line help, whether it is a command-line option, whether the numba
kernels read it and its bounds: `KernelParams` and the options of
pipeline.options are generated from it.
"""

from __future__ import annotations

import dataclasses
import enum
import math
import operator
import tomllib
from pathlib import Path
from typing import Any, Callable, NamedTuple, get_type_hints


class Optimizer(str, enum.Enum):
    """The optimizers of the catalogue; OPTIMIZERS says what each one does."""

    NONE = "none"
    LM = "lm"
    LBFGS = "lbfgs"
    GA = "ga"
    PSO = "pso"
    DE = "de"
    MDE = "mde"
    MDE_LM = "mde-lm"
    GA_ITERATIVE = "ga-iterative"
    LM_MDE = "lm-mde"
    GOLD = "gold"
    RICHARDSON_LUCY = "richardson-lucy"


# The catalogue: each optimizer's kernel code (the kernels: fwcore.engine.optimizers).
(OPT_NONE, OPT_DE, OPT_MDE, OPT_GA, OPT_PSO, OPT_LM, OPT_LBFGS, OPT_MDE_LM, OPT_GA_ITERATIVE, OPT_LM_MDE, OPT_GOLD,
 OPT_RICHARDSON_LUCY) = range(12)
# The least-squares fits on the valid samples that end (or are) an optimizer.
LOCAL_NONE, LOCAL_LM, LOCAL_LBFGS = range(3)
# Per-waveform messages (records.MESSAGES spells them out).
MSG_NO_ECHOES, MSG_CONVERGED, MSG_MAX_GENERATIONS, MSG_MAX_ITERATIONS, MSG_NOT_OPTIMIZED = range(5)


@dataclasses.dataclass(frozen=True)
class OptimizerSpec:
    """A catalogue entry: what the kernels do for this optimizer (fwcore.engine.optimizers.run_optimizer and
    find_own_echoes branch on these, never on lists of codes). All but the description reach KernelParams."""

    code: int
    description: str  # the command line's help for --optimizer
    search: bool = False  # a population search on Eq. 9 over the whole waveform (its kind: the code)
    local: int = LOCAL_NONE  # the least-squares fit on the valid samples that ends it, or is it
    # The local fit weights each sample by 1 / its noise sigma. L-BFGS fits the plain sum of squares,
    # as its rows of docs/compare.md were measured (LM weighs by the noise model).
    noise_weighted: bool = True
    search_where_local_fails: bool = False  # the local fit first; the search only where it fails (lm-mde)
    own_echoes: bool = False  # finds its own echoes (not the initial estimate's); no selection after it
    deconvolution: bool = False  # its echoes are the lobes of a deconvolved profile

    def kernel_values(self) -> dict[str, Any]:
        """The entry as KernelParams holds it: the code as `method`, without the description."""
        values = {f.name: getattr(self, f.name) for f in dataclasses.fields(self) if f.name != "description"}
        return {"method": values.pop("code"), **values}


OPTIMIZERS: dict[Optimizer, OptimizerSpec] = {
    Optimizer.NONE: OptimizerSpec(OPT_NONE, "the initial estimate as is"),
    Optimizer.LM: OptimizerSpec(OPT_LM, "Levenberg-Marquardt from the initial estimate", local=LOCAL_LM),
    Optimizer.LBFGS: OptimizerSpec(OPT_LBFGS, "projected L-BFGS from the initial estimate", local=LOCAL_LBFGS,
                                   noise_weighted=False),
    Optimizer.GA: OptimizerSpec(OPT_GA, "real-coded genetic algorithm", search=True),
    Optimizer.PSO: OptimizerSpec(OPT_PSO, "global-best particle swarm", search=True),
    Optimizer.DE: OptimizerSpec(OPT_DE, "differential evolution, DE/rand/1 (the method's Eq. 4)", search=True),
    Optimizer.MDE: OptimizerSpec(OPT_MDE, "modified DE with chaotic scale factors", search=True),
    Optimizer.MDE_LM: OptimizerSpec(OPT_MDE_LM, "MDE, then an LM polish of its best individual", search=True,
                                    local=LOCAL_LM),
    Optimizer.GA_ITERATIVE: OptimizerSpec(OPT_GA_ITERATIVE, "the patent's binary GA, adding echoes until R^2 is "
                                          "reached", local=LOCAL_LM, own_echoes=True),
    Optimizer.LM_MDE: OptimizerSpec(OPT_LM_MDE, "LM; where it does not converge and its fit fails the noise model's "
                                    "chi^2 test, MDE around it, polished by LM, kept when clearly better",
                                    search=True, local=LOCAL_LM, search_where_local_fails=True),
    Optimizer.GOLD: OptimizerSpec(OPT_GOLD, "Gold deconvolution with the system response, echoes from the "
                                  "recovered profile's lobes", own_echoes=True, deconvolution=True),
    Optimizer.RICHARDSON_LUCY: OptimizerSpec(OPT_RICHARDSON_LUCY, "Richardson-Lucy deconvolution with the system "
                                             "response, echoes from the profile's lobes", own_echoes=True,
                                             deconvolution=True),
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


def setting(default: Any, help: str | None = None, *, symbol: str = "", option: bool = False,
            kernel: bool | Callable[[Any], dict[str, Any]] = False, within: str = "", why: str = "",
            refit: bool | tuple[float, float] = False) -> Any:
    """A DecompositionConfig field and what the rest of the code needs to know of it, in its metadata.

    help: the command line's help (default: the symbol); symbol: the paper's name of it (NP, G, CR);
    option: a command-line option --the-name (pipeline.options.add_method_arguments); kernel: True
    when the numba kernels read it as is (a KernelParams field of its name), or a function from its
    value to the KernelParams fields it becomes; within: its interval, "[0, 1]", "(0, inf)", checked
    with `why` said after the message; refit: the viewer's Try may change it (pipeline.view.params), a
    number within these bounds (lo, hi), closer than `within` so that one refit takes seconds; True for
    a choice or a flag.
    """
    if within:
        _interval(within)  # a mistyped interval fails at import, not at the first check
    return dataclasses.field(default=default, metadata={
        "help": help or symbol or None, "symbol": symbol, "option": option, "kernel": kernel, "within": within,
        "why": why, "refit": refit})


def _interval(text: str) -> tuple[float, float, bool, bool]:
    """'[0, 1)' -> (0.0, 1.0, True, False): the bounds and whether each is included."""
    lo, hi = (float(v.strip()) for v in text[1:-1].split(","))
    if text[0] not in "[(" or text[-1] not in "])":
        raise ValueError(f"an interval is written [a, b], (a, b], [a, b) or (a, b), not {text!r}")
    return lo, hi, text[0] == "[", text[-1] == "]"


def _interval_error(name: str, value: Any, metadata: dict) -> str | None:
    """The message for a value outside the setting's interval (None: inside, or no interval)."""
    lo, hi, lo_closed, hi_closed = _interval(metadata["within"])
    if value is None or ((lo <= value if lo_closed else lo < value) and (value <= hi if hi_closed else value < hi)):
        return None
    label = f"{name} ({metadata['symbol']})" if metadata["symbol"] else name
    if hi == math.inf:
        bound = (f"at least {lo:g}" if lo_closed else "positive" if lo == 0 else f"above {lo:g}")
        message = f"{label} must be {bound}"
    else:
        message = f"{label} must lie in {metadata['within']}"
    return message + (f": {metadata['why']}" if metadata["why"] else "")


@dataclasses.dataclass(frozen=True)
class DecompositionConfig:
    """Every method parameter of a decomposition run."""

    optimizer: Optimizer = setting(Optimizer.LM_MDE, option=True, refit=True,
                                   kernel=lambda optimizer: OPTIMIZERS[optimizer].kernel_values())
    model: Model = setting(Model.AUTO, "the echoes' shape: system (the instrument's measured response), generalized "
                           "(the method's generalized Gaussian), gaussian; default auto: per file, the one of system "
                           "and generalized that predicts its held-out samples better (run.json says which and why)",
                           option=True, refit=True,
                           # the system model's alpha comes from its table, the Gaussian's is sqrt(2)
                           kernel=lambda model: {"alpha_fixed": model in (Model.SYSTEM, Model.GAUSSIAN)})
    # Evolution: population NP and generations G (the MDE paper: 60 and 80); with tol > 0,
    # G is the most a waveform may take.
    population: int = setting(60, symbol="NP", option=True, kernel=True, within="[5, inf)",
                              why="MDE draws 4 distinct partners", refit=(5, 200))
    generations: int = setting(200, symbol="G", option=True, kernel=True, within="[0, inf)", refit=(0, 1000))
    crossover_rate: float = setting(0.9, symbol="CR", option=True, kernel=True, within="[0, 1]")
    # MDE's chaotic scale factors: t seeds, k logistic-map iterations, range [a, b].
    chaos_seeds: int = setting(1, symbol="t", option=True, kernel=True, within="[1, inf)")
    chaos_iterations: int = setting(5, symbol="k", option=True, kernel=True, within="[1, inf)")
    scale_min: float = setting(0.2, symbol="a", option=True, kernel=True)
    scale_max: float = setting(1.0, symbol="b", option=True, kernel=True)
    # Write each DE/MDE winner back at once (asynchronous DE) instead of once per generation.
    immediate: bool = setting(False, kernel=True)
    # Denoising: Gaussian filter sigma = smoothing_factor * system pulse sigma,
    # unless smoothing_sigma_ps is given (0 turns smoothing off).
    smoothing_factor: float = setting(0.25, refit=(0.0, 10.0))
    smoothing_sigma_ps: float | None = setting(None, option=True)
    fit_target: FitTarget = setting(FitTarget.DENOISED, option=True,
                                    kernel=lambda target: {"fit_denoised": target is FitTarget.DENOISED})
    # With the denoised target: where the final fit's chi^2 per degree of freedom on the raw samples,
    # under the noise model, exceeds raw_polish_gate, LM refits the raw samples from it (the smoothing's
    # bias on steep, high-count rises; NEON raw error 254 -> 239 DN, Leica and the flight unchanged).
    raw_polish: bool = setting(True, "LM refits the raw samples where the denoised fit fails the noise model there "
                               "(default on)", option=True, kernel=True)
    raw_polish_gate: float = setting(1.5, "chi^2 per degree of freedom on the raw samples above which the raw polish "
                                     "runs (1.5)", option=True, kernel=True, within="[0, inf)")
    # Initial estimate: an echo must rise noise_threshold x the noise at its sample above background.
    noise_threshold: float = setting(3.0, kernel=True, within="(0, inf)", refit=(0.01, 100.0))
    # `fast`: with the selection on, no peak within 0.75 pulse widths of a peeled echo and under this share of its
    # amplitude is proposed: it is mostly the residual of a peeled echo wider than its estimate, which the fit
    # merges back and a refit drops (RIEGL-like flight: 0.12 -> 0.06 dropped a pulse; the simulated flights'
    # scores within their noise). Off by default: a clean pair 0.64 W apart then reads as one broad echo.
    flank_ratio: float = setting(0.0, "the initial estimate proposes no peak within 0.75 pulse widths of an echo "
                                 "and under this share of its amplitude (fast: 0.2)", option=True, kernel=True,
                                 within="[0, 1)")
    noise_estimator: NoiseEstimator = setting(NoiseEstimator.ROBUST, option=True,
                                              kernel=lambda e: {"robust_noise": e is NoiseEstimator.ROBUST})
    # sigma_noise is floored here (digitizer units): the quantisation of an integer digitizer is
    # uniform noise of 1/sqrt(12) DN whatever the analogue noise below it.
    min_noise_sigma: float = setting(1.0 / math.sqrt(12.0), kernel=True, within="[0, inf)")
    # The noise model of a sample with signal s above background (digitizer units):
    # variance = sigma_noise**2 + g s + (shape_tolerance s)**2. g (Poisson-like shot noise) is
    # fitted per waveform to the residual of the optimizer's fit; shape_tolerance, how far the
    # system's pulse may depart from a generalized Gaussian without being another echo, is the file's
    # (fwcore.instrument.pulse.SystemPulse). A shape tolerance of 0 and signal_dependent_noise=False give
    # the method's constant noise.
    signal_dependent_noise: bool = setting(True, kernel=True)
    max_echoes: int = setting(12, option=True, kernel=True, within="[1, inf)", refit=(1, 24))
    alpha_min: float = setting(1.0, kernel=True)
    alpha_max: float = setting(2.6, kernel=True)
    # Filter of spurious echoes (the method's section 1.2). The paper's values are 0.2, -, 1.0, 1.0, 3.0.
    # The paper's 20% drops weak ground returns under canopy (measured on the Leica system returns);
    # the SNR floor is low because the BIC selection already decides which echoes the data supports:
    # on the simulated flight a floor of 6 sigma loses half the true echoes between 5 and 10 sigma
    # (recall 0.88); 3 sigma, the initial estimate's own threshold, keeps them, and drops the 2 DN bumps that put
    # echoes 5-12 m under the Leica sample's ground (2 sigma: 7 such echoes; precision on resolvable echoes of the
    # simulated Leica / RIEGL flights 0.917 / 0.990 -> 0.923 / 0.996 at the same recall).
    min_amplitude_ratio: float = setting(0.05, kernel=True, refit=(0.0, 1.0))
    min_snr: float = setting(3.0, "echoes below this x sigma_noise are weak", option=True, kernel=True,
                             refit=(0.0, 1000.0))
    min_separation_factor: float = setting(1.0, kernel=True, refit=(0.0, 10.0))  # x system pulse FWHM
    min_width_factor: float = setting(0.5, kernel=True)  # x system pulse FWHM
    max_width_factor: float = setting(3.0, kernel=True)  # x system pulse FWHM
    # Of two echoes closer than the separation (one unresolved return), the earlier is kept when it is at
    # least this share of the later's amplitude; otherwise the weaker. 1 (the method's rule): the weaker
    # goes. 0.35 reports an unresolved return at its first surface, as the Leica system's detector does
    # (its returns recovered 0.973 -> 0.980), but costs the simulated flight 0.7 points of recall and
    # 0.9 of precision (README, "Decisions where the method is silent").
    first_echo_ratio: float = setting(1.0, "of two echoes closer than the pulse width, the earlier stays when its "
                                      "amplitude is at least this share of the later's (default 1: the weaker goes; "
                                      "0.35: the first surface)", option=True, kernel=True, within="[0, inf)")
    # Model-order selection after the optimizer: drop the echoes the filter flags when the raw
    # samples do not need them, add one where the residual holds an echo, each by the Bayesian
    # information criterion under the noise model, with warm-started LM refits.
    select_echoes: bool = setting(True, "model-order selection: drop and add echoes by the BIC with LM refits "
                                  "(default on)", option=True, kernel=True, refit=True)
    # A pulse of one strong echo on the tabulated response (every other candidate the filter would drop against
    # it): LM fits that echo alone, and the fit stands where the raw samples pass the noise model (chi^2 per
    # degree of freedom at most raw_polish_gate); elsewhere the full path runs as before
    # (fwcore.engine.strong_echo). The selection and the raw polish then have nothing to ask.
    strong_echo_fit: bool = setting(True, "a pulse of one strong echo (the others would be filtered) is fitted "
                                    "alone where that passes the noise model (default on)", option=True,
                                    kernel=True)
    # echoes the selection may add per waveform
    max_added_echoes: int = setting(2, kernel=True, within="[0, inf)", refit=(0, 8))
    # A waveform of more echoes than this refits a candidate locally (fwcore.engine.selection.local_refit: the
    # echoes the candidate reaches move, over their samples; one joint refit ends the step): LVIS's tropical
    # forest (1024 samples, 12 echoes) decomposes 1.6x faster; a waveform of few echoes refits all as before.
    local_refit_echoes: int = setting(6, "model-order selection refits a candidate locally where a waveform has "
                                      "more echoes than this", kernel=True, within="[0, inf)")
    # The add step tries an echo where the residual's height clears this x sigma_noise: a shoulder's residual is
    # a fraction of the echo the refit then finds, so its floor stays below the filter's min_snr.
    add_min_snr: float = setting(2.0, kernel=True, within="[0, inf)")
    # LM's (L-BFGS gets 4x as many)
    lm_iterations: int = setting(50, option=True, kernel=True, within="[1, inf)", refit=(1, 1000))
    # LM stops when an accepted step lowers the weighted sum of squares (chi^2) by less than this share of
    # it: 1e-4 of a chi^2 of m samples is a few hundredths, far below what the data tell apart. 1e-6 kept
    # the tabulated model's LM creeping over its table's kinks (RIEGL: 11% of fits ran out of iterations),
    # for the same echoes: Leica's returns, RIEGL's ghosts and the flights alike, NEON's raw error within 0.2%.
    lm_tolerance: float = setting(1e-4, "LM stops when a step lowers the sum of squares by less than this share of "
                                  "it", option=True, kernel=True, within="(0, 1)")
    # ... or by less than this much of chi^2 itself (the fits are weighted by the noise: chi^2 is in noise units).
    # A gain of 0.05 moves no parameter by more than a fifth of its standard error (Delta chi^2 = 1 is one);
    # on a short window, where chi^2 is about its 60 samples, it ends the fit a step before 1e-4 of chi^2 does.
    # (The deconvolutions' amplitude fit keeps the relative rule alone.)
    lm_chi2_tolerance: float = setting(0.05, "LM also stops when a step lowers chi^2 by less than this",
                                       option=True, kernel=True, within="[0, inf)")
    # `fast`: LM does not take an (undamped) step whose linear model promises less than lm_chi2_tolerance: near the
    # minimum the prediction is the gain, and the Jacobian at the step it would stop after is never used
    # (RIEGL-like flight: 4.9 -> 3.0 Jacobians a pulse). Off by default: lm-mde's MDE searches where LM does not
    # converge, and the stop moves that line (Leica sample: 0.986 of the system's returns -> 0.983).
    lm_predicted_stop: bool = setting(False, "LM stops before a step predicted to lower chi^2 by less than "
                                      "lm_chi2_tolerance (fast: on)", option=True, kernel=True)
    # Population methods stop when the spread of the population's fitness is small
    # (SciPy's rule: std(fitness) <= atol + tol |mean(fitness)|), at most after `generations`.
    # tol = atol = 0 runs every generation (the paper's fixed G).
    tol: float = setting(0.01, "MDE/DE stop when std(fitness) <= atol + tol |mean(fitness)| (with tol > 0, atol "
                         "grows by noise_tol x the noise's spread of the fitness)", option=True, kernel=True,
                         within="[0, inf)")
    atol: float = setting(0.0, kernel=True, within="[0, inf)")
    # With tol > 0, atol grows by noise_tol x the spread that the noise alone gives Eq. 9's fitness,
    # sigma_noise sqrt(m (1 - 2 / pi)): a population that agrees to within the noise has converged
    # (RIEGL, system model: MDE 2.7x faster, the same echoes). White noise's figure: the default fits the
    # denoised samples, whose correlated noise spreads the fitness less, so this stops a little early.
    noise_tol: float = setting(1.0, kernel=True, within="[0, inf)")
    # With tol > 0, DE and MDE also stop when their best individual improved by no more than that atol over
    # the last stall_generations generations (pymoo's ftol over a period): a search whose best moves by
    # less than the noise's share of the fitness has found what it will find. 0: off. RIEGL (system model):
    # two waveforms' wandering baselines kept lm-mde's MDE searching 142-200 generations for no better fit,
    # 40% of the default's time; the same raw error on RIEGL and NEON with 10, 20 or no stall rule.
    stall_generations: int = setting(20, "with tol > 0, MDE/DE also stop when their best fitness fell by no more "
                                     "than atol over this many generations (0: never)", option=True, kernel=True,
                                     within="[0, inf)")
    # GA: probability that a parameter mutates (the crossover rate is CR above).
    ga_mutation_rate: float = setting(0.1, kernel=True, within="[0, 1]")
    # ga-iterative (the patent): add echoes while R^2 is below this; generations per GA fit.
    ga_iterative_r2: float = setting(0.98, option=True, kernel=True, within="(0, 1]")
    ga_iterative_generations: int = setting(1000, option=True, kernel=True, within="[1, inf)")
    # gold, richardson-lucy: multiplicative iterations of the deconvolution
    deconvolution_iterations: int = setting(200, kernel=True, within="[1, inf)")
    # lm-mde: MDE searches where LM did not converge in lm_iterations and its fit's chi^2 per degree of
    # freedom on the raw samples, under the noise model with its Poisson-like term, exceeds this. Where LM
    # converged, a failing fit is the model's misfit, which MDE ends in too: after a converged LM it
    # improved the raw error by more than 1% on 2 of 1,037 waveforms (NEON, Leica, RIEGL; docs/decisions.md).
    mde_gate: float = setting(2.0, "lm-mde: MDE searches where LM did not converge and its fit's chi^2 per degree "
                              "of freedom exceeds this", option=True, kernel=True, within="[0, inf)")
    seed: int = setting(0, option=True)

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
        for field in dataclasses.fields(self):
            if field.metadata.get("within"):
                message = _interval_error(field.name, getattr(self, field.name), field.metadata)
                self._check(message is None, message or "")
        self._check(0.0 <= self.scale_min < self.scale_max,
                    "the scale factor range [scale_min, scale_max] must satisfy 0 <= a < b")
        self._check(0.5 <= self.alpha_min <= math.sqrt(2) <= self.alpha_max <= 4.0,
                    "need 0.5 <= alpha_min <= sqrt(2) <= alpha_max <= 4")
        self._check(self.smoothing_factor >= 0 and (self.smoothing_sigma_ps or 0) >= 0,
                    "smoothing must be >= 0")
        self._check(0 <= self.min_width_factor < self.max_width_factor and self.max_width_factor > 1,
                    "need 0 <= min_width_factor < max_width_factor and max_width_factor > 1 (x the pulse FWHM)")

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
        pulse says (fwcore.instrument.pulse.SystemPulse): the echo model it decides where the config's is auto, and
        its measurements (MEASURED_KERNEL_VALUES)."""
        from_file = {"model": model, "shape_tolerance": shape_tolerance}
        values = {}
        for field in dataclasses.fields(self):
            kernel = field.metadata.get("kernel")
            value = from_file.pop(field.name) if kernel and field.name in from_file else getattr(self, field.name)
            if kernel is True:
                values[field.name] = value
            elif kernel:
                values.update(kernel(value))
        return KernelParams.typed(**values, **from_file)

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
        """A config from its to_dict (run.json, a table's metadata) or a TOML table; a retired setting at the value
        it always held (an earlier run's) is dropped."""
        values = current_settings(values)
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


# Settings an earlier fwl declared, at the one value every run held (now constants of the kernels,
# fwcore.engine.optimizers.evolution): an earlier run's configuration that names them reads the same.
RETIRED_SETTINGS: dict[str, Any] = {"de_scale_factor": 0.5, "init_spread": 0.25}


def current_settings(values: dict[str, Any]) -> dict[str, Any]:
    """A configuration's values without the retired settings at their one value (another value stays, and is then
    refused as unknown: the run it describes cannot be made again)."""
    return {k: v for k, v in values.items() if not (k in RETIRED_SETTINGS and v == RETIRED_SETTINGS[k])}


# What the kernels read that is no method setting: the file's own measurements, given to kernel_params.
MEASURED_KERNEL_VALUES: dict[str, type] = {"shape_tolerance": float}


def _kernel_fields() -> list[tuple[str, type]]:
    """KernelParams' fields: the kernel settings (their names and types from the defaults), then the file's."""
    default = DecompositionConfig()
    kinds = get_type_hints(DecompositionConfig)
    fields: list[tuple[str, type]] = []
    for field in dataclasses.fields(DecompositionConfig):
        kernel = field.metadata.get("kernel")
        if kernel is True:
            fields.append((field.name, kinds[field.name]))
        elif kernel:
            fields += [(name, type(value)) for name, value in kernel(getattr(default, field.name)).items()]
    return fields + list(MEASURED_KERNEL_VALUES.items())


class KernelParams(NamedTuple("_KernelFields", _kernel_fields())):
    """DecompositionConfig as the kernels see it: the settings whose metadata says `kernel`, enums as codes
    and flags, and the file's measurements (MEASURED_KERNEL_VALUES); generated from the config's fields."""

    __slots__ = ()

    @classmethod
    def typed(cls, **values: Any) -> "KernelParams":
        """Each value as its field's type: numba compiles every kernel afresh for each tuple of argument
        types, so min_snr=8 (an int from JSON or TOML) beside min_snr=8.0 would cost a second full compile."""
        cast = {float: float, int: operator.index, bool: bool}  # index: an int setting of 2.5 stays an error
        kinds = get_type_hints(cls)
        return cls(**{name: cast[kinds[name]](values[name]) for name in cls._fields})


@dataclasses.dataclass(frozen=True)
class Preset:
    """A named configuration, one entry: the method's settings, and what it says of every file's pulse instead of
    what the file's plan measures (`overrides`: PulseOverrides' fields, fwcore.instrument.pulse, which builds them:
    `PulseOverrides.of_preset`)."""

    settings: dict[str, Any]
    overrides: dict[str, Any] = dataclasses.field(default_factory=dict)

    def config(self) -> DecompositionConfig:
        return DecompositionConfig(**self.settings)


# Named configurations (README, "Presets"): the defaults are the best we know.
# "paper": the MDE method exactly as published: its generalized Gaussian, its noise formula and constant
# noise, its filter (20% of the largest amplitude, widths from 1x to 3x the pulse), MDE for a fixed G = 80, no
# polish (neither LM's nor the raw one), no selection; its model taken as exact (a shape tolerance of 0).
# "fast": LM alone from the initial estimate, fewer and looser iterations, with the default's selection.
PRESETS: dict[str, Preset] = {
    "paper": Preset({"optimizer": Optimizer.MDE, "model": Model.GENERALIZED, "generations": 80, "tol": 0.0,
                     "atol": 0.0, "noise_estimator": NoiseEstimator.RESIDUAL, "min_noise_sigma": 1.0,
                     "signal_dependent_noise": False, "select_echoes": False,
                     "min_amplitude_ratio": 0.2, "min_snr": 0.0, "min_width_factor": 1.0, "raw_polish": False},
                    overrides={"shape_tolerance": 0.0}),
    # LM alone, stopping at a relative gain of 1e-3 (0.06 of chi^2 on RIEGL's 60 samples) or a gain of 0.3, made or
    # predicted; no weak peak proposed on an echo's flank, no echo added, no shot-noise term: the simulated flights'
    # recall, precision and RMSE and the Leica sample's returns within their noise (docs/decisions.md). The raw
    # polish stays: without it NEON's raw error is 263 DN, not 187.
    "fast": Preset({"optimizer": Optimizer.LM, "lm_iterations": 20, "lm_tolerance": 1e-3, "lm_chi2_tolerance": 0.3,
                    "lm_predicted_stop": True, "flank_ratio": 0.2, "max_added_echoes": 0,
                    "signal_dependent_noise": False}),
}
