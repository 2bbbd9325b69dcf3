"""The options of `fwl run`, defined once and checked before anything runs.

Our flags are a PipelineOptions subclass (`FwlOptions`): typed by argparse,
validated into one DecompositionConfig. Every other flag must be a Beam
option: an unknown or mistyped one is an error that names it and suggests the
closest known flag, where Beam alone would only warn and discard it.
"""

from __future__ import annotations

import argparse
import dataclasses
import difflib
import enum
import typing
from pathlib import Path
from typing import Any, Iterable, get_type_hints

from apache_beam.options.pipeline_options import DirectOptions, PipelineOptions, SetupOptions, StandardOptions

from fwcore.engine.config import OPTIMIZERS, PRESETS, DecompositionConfig
from fwcore.metrics.biomass import STRATUM_HELP
from fwcore.instrument.pulse import DEFAULT_PULSE_FWHM_PS, PulseOverrides
from fwcore.instrument.response import named_response
from fwcore.metrics.echo_column import PULSE_METRICS
from pipeline.forest_settings import ForestSettings

FORMATS = ("parquet", "las", "mcap", "copc")  # copc: only when asked (pipeline.copc)
DEFAULT_FORMATS = ("parquet", "las", "mcap")
# The runner when the command line names none: the DirectRunner with a worker process per core of a
# small machine. Any of these can be given on the command line; deploy/README.md shows the others.
RUNNER_DEFAULTS = {"runner": "DirectRunner", "direct_num_workers": 2, "direct_running_mode": "multi_processing"}
RUNNER_FLAGS = ("runner", "direct_num_workers", "direct_running_mode")


def runner_given(beam_args: list[str]) -> bool:
    """Whether the command line chose the runner or its workers (else RUNNER_DEFAULTS, which a small run may
    leave for the driver's own process: pipeline.run.Jobs)."""
    return any(a.split("=", 1)[0].lstrip("-") in RUNNER_FLAGS for a in beam_args if a.startswith("-"))


class OptionError(ValueError):
    """A command-line option that is unknown, mistyped or out of range; the message says how to fix it."""


def positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a whole number: {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be >= 1, not {value}")
    return value


def check_formats(formats) -> frozenset[str]:
    """The output formats asked for, checked (ValueError naming the unknown ones): the one check, for the
    command line and for callers of pipeline.run.run alike."""
    formats = frozenset(formats)
    unknown = sorted(formats - set(FORMATS))
    if unknown or not formats:
        raise ValueError(f"unknown output format(s) {', '.join(unknown) or '(none)'}; choose from {', '.join(FORMATS)}")
    return formats


def output_formats(text: str) -> list[str]:
    """A comma-separated list of formats, checked and sorted (a list: Beam sends its options to workers as JSON)."""
    try:
        return sorted(check_formats(f.strip() for f in text.split(",") if f.strip()))
    except ValueError as err:
        raise argparse.ArgumentTypeError(str(err)) from None


def l2a_algorithms(text: str) -> str:
    """--l2a-algorithms: selected | all | one of GEDI L2A's algorithms 1..6."""
    text = text.strip().lower()
    if text in ("selected", "all") or text in {str(a) for a in range(1, 7)}:
        return text
    raise argparse.ArgumentTypeError(f"choose selected, all or an algorithm 1..6, not {text!r}")


# fwl compare takes several of each (--optimizers, --model), not one
COMPARED = ("optimizer", "model")


def add_method_arguments(parser, compare: bool = False) -> None:
    """The decomposition's flags (shared by run, decompose-csv and compare), one per DecompositionConfig field
    whose metadata says `option`; None means "not given"."""
    g = parser.add_argument_group("method (defaults: the built-in configuration, then --preset, then --config)")
    g.add_argument("--config", help="TOML file with a [decomposition] table")
    g.add_argument("--preset", choices=sorted(PRESETS), help="a named configuration (see the README)")
    kinds = get_type_hints(DecompositionConfig)
    for field in dataclasses.fields(DecompositionConfig):
        if field.metadata.get("option") and not (compare and field.name in COMPARED):
            g.add_argument("--" + field.name.replace("_", "-"), dest=field.name, help=_option_help(field),
                           **_option_kind(kinds[field.name]))
    # the file's pulse, given instead of measured (pulse_overrides): not settings of the method
    g.add_argument("--system-pulse-fwhm-ps", dest="system_pulse_fwhm_ps", type=float,
                   help="the emitted pulse's FWHM (default: measured on each file's single-return pulses)")
    g.add_argument("--system-response", dest="system_response",
                   help="the instrument's response for --model system, instead of measuring it on each file: leica or "
                        "riegl (shipped), gaussian (of --system-pulse-fwhm-ps), a CSV whose first column holds it at "
                        "1 ns a sample (NEON's system_impulse.csv) or the JSON fwl info --system-response --json gives")
    g.add_argument("--shape-tolerance", dest="shape_tolerance", type=float,
                   help="relative departure of the pulse from the model that is not another echo (Leica: 0.06)")


def _option_kind(kind: Any) -> dict[str, Any]:
    """argparse's type, choices or action for a field of this type (X | None: X's)."""
    kind = next((k for k in typing.get_args(kind) if k is not type(None)), kind)
    if kind is bool:
        return {"action": argparse.BooleanOptionalAction}
    if isinstance(kind, type) and issubclass(kind, enum.Enum):
        return {"choices": [m.value for m in kind]}
    return {"type": kind}


def _option_help(field: dataclasses.Field) -> str | None:
    if field.name == "optimizer":  # the catalogue's own words for each
        return "; ".join(f"{o.value}: {spec.description}" for o, spec in OPTIMIZERS.items())
    return field.metadata["help"]


def decomposition_config(args: Any) -> DecompositionConfig:
    """Defaults <- preset <- TOML file <- explicit flags; DecompositionConfig validates the result once."""
    config = PRESETS[args.preset].config() if getattr(args, "preset", None) else DecompositionConfig()
    if getattr(args, "config", None):
        config = config.replace(**DecompositionConfig.from_toml(args.config).changes())
    overrides = {f.name: getattr(args, f.name) for f in dataclasses.fields(DecompositionConfig)
                 if getattr(args, f.name, None) is not None}
    return config.replace(**overrides)


def forest_settings(args: Any) -> ForestSettings:
    """--stratum, --l2a-algorithms and --pulse-metrics as one record (pipeline.forest_settings), unchecked."""
    return ForestSettings(args.stratum, args.l2a_algorithms, args.pulse_metrics)


def pulse_overrides(args: Any) -> PulseOverrides:
    """What the flags say of every file's pulse instead of measuring it: the preset's, then the explicit flags
    (--system-response: a name or a file, read once here)."""
    given = PulseOverrides.of_preset(getattr(args, "preset", None))
    fwhm = getattr(args, "system_pulse_fwhm_ps", None)
    if fwhm is not None:
        given = given.replace(fwhm_ps=fwhm)
    if getattr(args, "shape_tolerance", None) is not None:
        given = given.replace(shape_tolerance=args.shape_tolerance)
    if getattr(args, "system_response", None):
        given = given.replace(response=named_response(args.system_response, fwhm or DEFAULT_PULSE_FWHM_PS))
    return given


class FwlOptions(PipelineOptions):
    """The flags of `fwl run` (besides the input patterns), as Beam options."""

    @classmethod
    def _add_argparse_args(cls, parser) -> None:
        g = parser.add_argument_group("run")
        g.add_argument("--output", default="out/run",
                       help="output folder (default out/run): new, empty, or an earlier run's, which is replaced "
                             "(with --resume: an interrupted run's, which is completed)")
        g.add_argument("--formats", type=output_formats, default=",".join(DEFAULT_FORMATS),
                       help="comma-separated: parquet, las, mcap, copc (default parquet,las,mcap)")
        g.add_argument("--limit", type=positive_int, help="at most N pulses per input file")
        g.add_argument("--points-per-range", dest="points_per_range", type=positive_int, default=5000,
                       help="points per unit of work (default 5000)")
        g.add_argument("--laz", action="store_true", help="write the point clouds as LAZ")
        g.add_argument("--crs", help="the inputs' coordinate reference system, for inputs that name none or name it "
                                     "wrongly: an EPSG code (EPSG:25832), WKT or PROJJSON; every output carries it "
                                     "instead of what the inputs say")
        g.add_argument("--stratum", help=STRATUM_HELP)
        g.add_argument("--l2a-algorithms", dest="l2a_algorithms", type=l2a_algorithms, default="selected",
                       help="GEDI: whose ground and RH fill ground_z / rh: 'selected' (each shot's L2A-selected "
                            "algorithm where an L2A granule lies beside the L1B, else algorithm 1), a number 1..6 "
                            "(that algorithm for every shot), or 'all' (as selected, and every algorithm's in "
                            "ground_z_a1..a6 / rh_a1..a6)")
        g.add_argument("--verbose", action="store_true",
                       help="show Beam's and the workers' logs on the terminal (they always go to logs/)")
        g.add_argument("--pulse-metrics", dest="pulse_metrics", choices=PULSE_METRICS, default=PULSE_METRICS[0],
                       help="each small-footprint pulse's forest metrics: 'echoes' (default) from its decomposed "
                            "echoes, the last one its ground; 'full': GEDI L2A/L2B's on its waveform, the ground "
                            "return fitted again (GEDI and LVIS always take the full ones)")
        add_method_arguments(parser)
        add_radiometry_arguments(parser)


def add_radiometry_arguments(parser) -> None:
    """Range, backscatter and reflectance (fwcore.radiometry.equations); every value is relative unless calibrated."""
    g = parser.add_argument_group("radiometry (range, backscatter cross-section and coefficient, reflectance)")
    g.add_argument("--trajectory", help="the platform's trajectory for LAS inputs: an SBET (17 doubles a record, "
                                        "WGS 84, radians) or a CSV gps_time,x,y,z in the inputs' CRS")
    g.add_argument("--calibration-reference", dest="calibration_reference",
                   help="xmin,ymin,xmax,ymax=REFLECTANCE: a patch of known diffuse reflectance whose single returns "
                        "give the calibration constant (or a JSON file with bbox and reflectance)")
    g.add_argument("--calibration-constant", dest="calibration_constant", type=float,
                   help="C_cal, as an earlier run's run.json reports it")
    g.add_argument("--beam-divergence-mrad", dest="beam_divergence_mrad", type=float,
                   help="the beam divergence, full angle at 1/e^2 (default: the file's, where it records it)")


def radiometry_config(args: Any):
    """The radiometry flags as one RadiometryConfig, checked (RadiometryError, a ValueError, names the problem)."""
    from fwcore.radiometry.equations import RadiometryConfig, RadiometryError, parse_calibration_reference

    reference = getattr(args, "calibration_reference", None)
    constant = getattr(args, "calibration_constant", None)
    if reference and constant is not None:
        raise RadiometryError("give --calibration-reference or --calibration-constant, not both")
    trajectory = getattr(args, "trajectory", None)
    patch = parse_calibration_reference(reference) if reference else None
    divergence = getattr(args, "beam_divergence_mrad", None)
    if divergence is None and patch is not None:  # a patch's JSON may say what the flight's file cannot
        divergence = patch.beam_divergence_mrad
    return RadiometryConfig(trajectory=str(Path(trajectory).resolve()) if trajectory else None,  # workers' cwd differ
                            calibration_reference=patch, calibration_constant=constant,
                            calibration_source="given" if constant is not None else "none",
                            beam_divergence_mrad=divergence)


def _subclasses(cls: type) -> Iterable[type]:
    for sub in cls.__subclasses__():
        yield sub
        yield from _subclasses(sub)


def _beam_parser(dask: bool = True) -> argparse.ArgumentParser:
    """A parser of every Beam option (and ours), as Beam itself builds one to read its flags; with `dask`, the
    Dask runner's too (importing it loads dask, distributed and pandas: 0.3 s of a DirectRunner run's start)."""
    if dask:
        import apache_beam.runners.dask.dask_runner  # noqa: F401  registers the Dask runner's options
    parser = argparse.ArgumentParser(allow_abbrev=False, add_help=False, exit_on_error=False)
    for cls in dict.fromkeys(_subclasses(PipelineOptions)):
        cls._add_argparse_args(parser)
    return parser


def _closest(flag: str, known: Iterable[str]) -> str:
    name = flag.split("=", 1)[0]
    # our flags use dashes and Beam's underscores: compare without either
    plain = {k.replace("_", "-"): k for k in known}
    match = difflib.get_close_matches(name.replace("_", "-"), list(plain), n=1, cutoff=0.6)
    return f" (did you mean {plain[match[0]]}?)" if match else ""


def unknown_option_error(flags: list[str], known: Iterable[str]) -> OptionError:
    known = sorted(set(known))
    names = [f for f in flags if f.startswith("-")] or flags
    return OptionError("; ".join(f"unknown option {f.split('=', 1)[0]}{_closest(f, known)}" for f in names))


def check_beam_args(beam_args: list[str], ours: Iterable[str] = ()) -> PipelineOptions:
    """The Beam options of these flags, with the runner defaults where none is given.

    Raises OptionError for a flag no Beam option knows (naming the closest of Beam's and `ours`)
    and for a value of the wrong type.
    """
    # the Dask runner's options only where a flag names it or no other option knows a flag
    dask = any("dask" in a.lower() for a in beam_args)
    try:
        parser = _beam_parser(dask)
        _, unknown = parser.parse_known_args(beam_args)
        if unknown and not dask:
            parser = _beam_parser(dask=True)
            _, unknown = parser.parse_known_args(beam_args)
    except (argparse.ArgumentError, SystemExit) as err:  # a known flag with a bad value
        raise OptionError(str(err)) from None
    if unknown:
        known = [s for a in parser._actions for s in a.option_strings] + list(ours)
        raise unknown_option_error(unknown, known)
    options = PipelineOptions(beam_args)
    standard = options.view_as(StandardOptions)
    if standard.runner is None:
        standard.runner = RUNNER_DEFAULTS["runner"]
        direct = options.view_as(DirectOptions)
        given = {a.split("=", 1)[0].lstrip("-") for a in beam_args}
        if "direct_num_workers" not in given:
            direct.direct_num_workers = RUNNER_DEFAULTS["direct_num_workers"]
        if "direct_running_mode" not in given:
            direct.direct_running_mode = RUNNER_DEFAULTS["direct_running_mode"]
    # the workers import fwcore and pipeline from the installed package, not from a pickled session
    options.view_as(SetupOptions).save_main_session = False
    return options


def pipeline_runner(options: PipelineOptions):
    """The runner object to give beam.Pipeline: for the DirectRunner, the FnApiRunner it runs our pipeline on
    when Prism is unavailable; None lets Beam resolve any other runner by its name.

    Beam 2.77's DirectRunner first tries Prism, a Go binary it downloads from GitHub at each run: offline that
    fails in a moment, online it would run the job on another engine than the one we test (its own workers and
    logging, after a download). Built as the DirectRunner builds it, with the options for the SDK workers.
    """
    runner = options.view_as(StandardOptions).runner
    if not (isinstance(runner, str) and runner.rsplit(".", 1)[-1] == "DirectRunner"):
        return None
    from apache_beam.portability.api import beam_provision_api_pb2
    from apache_beam.runners.portability.fn_api_runner import fn_runner
    from apache_beam.runners.portability.portable_runner import JobServiceHandle
    encoded = JobServiceHandle.encode_pipeline_options(options.get_all_options())
    provision = fn_runner.ExtendedProvisionInfo(beam_provision_api_pb2.ProvisionInfo(pipeline_options=encoded))
    return fn_runner.FnApiRunner(provision_info=provision)


def is_dask(options: PipelineOptions) -> bool:
    runner = options.view_as(StandardOptions).runner
    return isinstance(runner, str) and runner.endswith("DaskRunner")
