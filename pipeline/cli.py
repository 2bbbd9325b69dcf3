"""The `fwl` command line."""

from __future__ import annotations

import argparse
import dataclasses
import os
import signal
import sys
import time
from pathlib import Path
from typing import NoReturn

import numpy as np

import fwcore
from fwcore.engine.config import DecompositionConfig, Model, Optimizer
from pipeline.claims import (check_suffix, claim_command_folder, claim_files, first_line_is, parquet_is_ours,
                             record_command_folder)
from pipeline.faults import WRITING, machine_fault
from fwcore.metrics.biomass import STRATUM_HELP
from pipeline.lock import folder_lock
from pipeline.logs import quiet_imports


# pipeline.options imports Beam: it is imported where used, after main's quiet_imports


def _config_from_args(args: argparse.Namespace) -> DecompositionConfig:
    from pipeline.options import decomposition_config

    return decomposition_config(args)


def forest_settings(args: argparse.Namespace):
    """What the flags give of the forest's metrics (pipeline.options.forest_settings)."""
    from pipeline.options import forest_settings as from_flags

    return from_flags(args)


def _overrides_from_args(args: argparse.Namespace):
    """What the flags give of every file's pulse (pipeline.options.pulse_overrides)."""
    from pipeline.options import pulse_overrides

    return pulse_overrides(args)


class _Renamed(argparse.Action):
    """An option's former spelling: still taken, with a warning naming the new one (fwl simulate's
    --system-response, now --sensor-response: fwl run's --system-response is an override of a file's pulse)."""

    def __call__(self, parser, namespace, values, option_string=None):
        new = next(a.option_strings[0] for a in parser._actions if a.dest == self.dest and a is not self)
        print(f"fwl: warning: {option_string} is deprecated here, give {new}", file=sys.stderr)
        setattr(namespace, self.dest, values)


def _add_method_options(parser: argparse.ArgumentParser, compare: bool = False) -> None:
    from pipeline.options import add_method_arguments

    add_method_arguments(parser, compare)


def _decompose_csv(args: argparse.Namespace) -> int:
    import pyarrow.parquet as pq

    from fwcore.engine.decompose import decompose_batch
    from fwcore.instrument.measure import read_csv_input
    from pipeline.tables import echo_table, waveform_table

    config = _config_from_args(args)
    # a file of another kind is named as such first
    csv = read_csv_input(args.input, config, _overrides_from_args(args), args.outgoing, args.sample_spacing_ps)
    output = check_suffix("fwl decompose-csv", args.output, (".parquet",), "a Parquet echo table")
    waveform_path = output.with_name(output.stem + ".waveforms.parquet")
    claim_files("fwl decompose-csv", [output, waveform_path], parquet_is_ours, args.overwrite)
    pulse, model = csv.pulse, csv.pulse.echo_model(config.model)
    width_source = pulse.fwhm_source
    if width_source.startswith("estimated"):  # nothing says it: measured on the returns, and said so
        print(f"{args.input}: no --outgoing: system pulse FWHM {pulse.fwhm_ps:.0f} ps {width_source}")
    if pulse.model_choice:
        print(f"{args.input}: model {pulse.model_choice}")
    if model is Model.SYSTEM:
        print(f"{args.input}: system response {pulse.response_source}"
              if pulse.response else f"{args.input}: no system response measured: echoes are Gaussians")
    ids = csv.waveform_id
    start = time.perf_counter()
    result = decompose_batch(csv.batch, config, pulse, threads=args.threads)
    seconds = time.perf_counter() - start
    output.parent.mkdir(parents=True, exist_ok=True)
    def with_width_source(table):
        return table.replace_schema_metadata({**table.schema.metadata, b"fwlidar.system_pulse_fwhm_source":
                                              width_source.encode()})

    pq.write_table(with_width_source(echo_table(ids, result, config, pulse)), output)
    n_samples = np.array([v.sum() for v in csv.waveforms.valid])
    pq.write_table(with_width_source(waveform_table(ids, result, config, pulse, n_samples)), waveform_path)
    ok = result.status == 0
    print(f"{args.input}: {len(result)} waveforms ({(~ok).sum()} not decomposed), "
          f"{result.amplitude.size} echoes ({(result.reject == 0).sum()} kept); "
          f"optimizer {config.optimizer.value}, model {model.value}, "
          f"system pulse FWHM {pulse.fwhm_ps:.0f} ps ({width_source})")
    print(f"mean fit error (Eq. 9, denoised) {result.fit_error[ok].mean():.1f}, "
          f"vs raw samples {result.fit_error_raw[ok].mean():.1f}, RMSE {result.rmse[ok].mean():.2f}, "
          f"R2 {result.r2[ok].mean():.4f}")
    print(f"{seconds:.2f} s ({len(result) / seconds:.1f} waveforms/s, including compilation on a first run)")
    print(f"wrote {output} and {waveform_path}")
    return 0


def _exit_interrupted(message: str) -> NoReturn:
    """Say why on stderr and end now with EXIT_INTERRUPTED: once a KeyboardInterrupt crossed one of Beam's compiled
    frames, even caught, Python ends by SIGINT (-2, not 130) and would wait for Beam's threads; the run removed
    its partial files already."""
    from pipeline.summary import EXIT_INTERRUPTED

    print(message, file=sys.stderr, flush=True)
    sys.stdout.flush()
    os._exit(EXIT_INTERRUPTED)


def resume_command(argv: list[str]) -> str:
    """The command that goes on with a stopped run: the same one, with --resume."""
    import shlex

    return "fwl " + shlex.join([a for a in argv if a != "--resume"] + ["--resume"])


def _run(args: argparse.Namespace, beam_args: list[str]) -> int:
    from pipeline.options import radiometry_config
    from pipeline.run import RunStopped, run
    from pipeline.summary import EXIT_MACHINE

    config = _config_from_args(args)
    radiometry = radiometry_config(args)
    try:
        summary = run(args.inputs, args.output, config, args.formats, args.limit, args.points_per_range, args.laz,
                      beam_args, verbose=args.verbose, resume=args.resume, radiometry=radiometry, crs=args.crs,
                      overrides=_overrides_from_args(args), forest=forest_settings(args))
    except RunStopped as stopped:  # the machine's fault: one line per cause, nothing in rejected/
        for line in stopped.lines(resume_command(args.argv)):
            print(f"fwl run: stopped: {line}", file=sys.stderr)
        kept = f"{stopped.finished} of {stopped.ranges} ranges finished and are kept; " if stopped.ranges else ""
        print(f"fwl run: {args.output} holds an incomplete run (no run.json): {kept}no pulse was rejected for this "
              f"(exit code {EXIT_MACHINE})", file=sys.stderr)
        return EXIT_MACHINE
    except KeyboardInterrupt:
        _exit_interrupted(f"fwl run: interrupted; {args.output} holds an incomplete run (no run.json): "
                          f"rerun the same command with --resume to complete it")
    if args.resume and summary.get("taken") != "resumed":
        said = {"new": "nothing to resume: a new run", "complete": "already complete: nothing to do"}
        print(f"fwl run --resume: {args.output}: {said.get(summary.get('taken'), said['complete'])}")
    elif summary.get("ranges_reused"):
        print(f"resumed: {summary['ranges_reused']} of {summary['ranges']} ranges reused")
    c = summary["counts"]
    problems = f", problems {c['problems']}" if c.get("problems") else ""  # ranges lost whole, missing records
    print(f"pulses read {c['pulses_read']} = decomposed {c['pulses_decomposed']} + rejected {c['pulses_rejected']}; "
          f"files rejected {c['files_rejected']}{problems}; echoes kept {c['echoes_kept']}, "
          f"spurious {c['echoes_spurious']}")
    processed = summary.get("pulses_processed", c["pulses_read"])
    now = f" (of the {processed} processed now; the rest were reused)" if processed != c["pulses_read"] else ""
    print(f"{summary['seconds']:.1f} s, {summary['pulses_per_second']} pulses/s{now}; "
          f"summary in {args.output}/run.json")
    _say_what_was_not_done(summary, args.output)
    return summary["exit_code"]


def _say_what_was_not_done(summary: dict, output: str) -> None:
    """Each input rejected whole with its first reason, each match that is no input with why; rejected/ named
    only for what only it says (pulses rejected, ranges lost)."""
    for entry in summary.get("not_inputs", []):  # nothing given goes unaccounted
        print(f"not an input: {entry['path']}: {entry['reason']}")
    for entry in summary["inputs"]:
        if "rejected_because" in entry:
            print(f"rejected: {entry['rejected_because']}")
    c = summary["counts"]
    if c["pulses_rejected"] or c.get("problems"):
        print(f"{summary['status']}: see {output}/rejected/ for the reasons (exit code {summary['exit_code']})")
    elif summary["status"] != "complete":
        print(f"{summary['status']}: exit code {summary['exit_code']}")


def _watch(args: argparse.Namespace, beam_args: list[str]) -> int:
    from pipeline.options import check_beam_args, radiometry_config
    from pipeline.run import check_run_arguments, run, run_settings
    from pipeline.watch import watch

    config = _config_from_args(args)
    radiometry = radiometry_config(args)
    if radiometry.calibration_reference is not None:
        raise ValueError("fwl watch: a reference patch lies in one flight line, not in every batch: find C_cal once "
                         "with fwl run --calibration-reference on that line, then give --calibration-constant")
    formats = check_run_arguments(args.formats, args.limit, args.points_per_range)
    if not args.poll > 0:
        raise ValueError(f"--poll must be a number of seconds > 0, not {args.poll}")
    check_beam_args(beam_args)  # a mistyped option stops here, not at the first file
    overrides = _overrides_from_args(args)
    forest = forest_settings(args).checked()  # a bad stratum stops here, not at a batch
    settings = run_settings(config, formats, args.limit, args.points_per_range, args.laz, radiometry, args.crs,
                            overrides, forest)
    running = []

    def run_batch(paths: list[str]) -> dict:
        running[:] = [paths]  # until it ends: an interruption meanwhile names it
        try:
            summary = run(paths, args.output, config, formats, args.limit, args.points_per_range, args.laz,
                          beam_args, verbose=args.verbose, add=True, radiometry=radiometry, crs=args.crs,
                          overrides=overrides, forest=forest)
        except Exception:  # failed, not interrupted: the watch goes on, idle
            running.clear()
            raise
        running.clear()
        return summary

    def stop(signum, frame):
        raise KeyboardInterrupt

    # a clean stop on Ctrl-C and on the TERM of a service manager, even when started with SIGINT ignored (`&`)
    previous = signal.signal(signal.SIGINT, signal.default_int_handler), signal.signal(signal.SIGTERM, stop)
    try:
        with folder_lock(args.output, "fwl watch"):  # for the whole watch: its batches' runs take it again
            watch(args.folder, args.output, config, settings, run_batch, args.poll, args.once,
                  lambda line: print(line, flush=True))
    except KeyboardInterrupt:
        if running:
            _exit_interrupted(f"fwl watch: interrupted while processing "
                              f"{', '.join(Path(p).name for p in running[0])}; start fwl watch again to go on "
                              f"(their finished ranges are kept)")
        print("fwl watch: stopped", flush=True)
    finally:
        signal.signal(signal.SIGINT, previous[0])
        signal.signal(signal.SIGTERM, previous[1])
    return 0


def _compare(args: argparse.Namespace) -> int:
    from fwcore.studies.comparison import run_comparison

    config = _config_from_args(args)
    optimizers = [Optimizer(o.strip()) for o in args.optimizers.split(",") if o.strip()]
    models = [Model(m.strip()) for m in args.models.split(",") if m.strip()]
    if Model.AUTO in models:  # a comparison names what it compares; auto is a choice between two of them
        raise ValueError("fwl compare --model takes system, generalized, gaussian (auto chooses between the first two)")
    pulses = [int(p) for p in args.pulses.split(",")] if args.pulses else None
    claim_command_folder("fwl compare", Path(args.output), args.overwrite)
    print(f"fwl compare: {args.input}: {', '.join(o.value for o in optimizers)} x "
          f"{', '.join(m.value for m in models)} -> {args.output}")
    summary = run_comparison(args.input, args.output, config, optimizers, models, args.limit, pulses,
                             args.distance, args.budget, args.threads, args.outgoing, _overrides_from_args(args))
    for row in summary["rows"]:
        print(f"  {row['optimizer']:13} {row['model']:11} fit error {row['fit_error']:8.1f}  R2 {row['r2']:.4f}  "
              f"{row['waveforms_per_second']:9.1f} waveforms/s")
    if "fast" in summary:
        fast = summary["fast"]
        print(f"fastest within 5% of MDE's fit error {summary['paper_fit_error']:.1f}: {fast['family']} "
              f"{fast['setting']} ({fast['fit_error']:.1f}, {fast['waveforms_per_second']:.1f} waveforms/s)")
    record_command_folder("fwl compare", Path(args.output), summary["written"])
    print(f"wrote {', '.join(summary['written'])} in {args.output}")
    return 0


def _simulate(args: argparse.Namespace) -> int:
    from fwcore.instrument.response import SHIPPED_SPACING_PS, named_response
    from fwcore.studies.forest import FOREST_SAMPLES
    from fwcore.studies.forest_truth import TRUTH_RASTERS, truth_raster_path
    from fwcore.studies.simulate import SceneConfig, SensorConfig
    from fwcore.studies.truth import calibration_path, trajectory_path, truth_path, write_flight

    output = check_suffix("fwl simulate", args.output, (".las", ".laz"), "a LAS file (its truth beside it)")
    # the flight's files are ours as a whole when its truth is: the one that carries fwl's mark
    claim_files("fwl simulate", [output, truth_path(output), trajectory_path(output), calibration_path(output)]
                + [truth_raster_path(output, name) for name in TRUTH_RASTERS]
                + ([output.with_suffix(".wdp")] if args.format != "las14-internal" else []),
                lambda _: parquet_is_ours(truth_path(output)), args.overwrite)
    response = named_response(args.sensor_response, args.pulse_fwhm_ps) if args.sensor_response else None
    if response is not None:  # the instrument's own pulse width and, unless given, its digitizer's spacing
        args.pulse_fwhm_ps = response.fwhm_ps
        args.sample_spacing_ps = args.sample_spacing_ps or SHIPPED_SPACING_PS.get(args.sensor_response, 1000.0)
    sensor = SensorConfig(pulse_fwhm_ps=args.pulse_fwhm_ps, sample_spacing_ps=args.sample_spacing_ps or 1000.0,
                          samples_per_packet=args.samples or (FOREST_SAMPLES if args.scene == "forest" else 200), digitizer_gain=args.gain, digitizer_offset=args.offset,
                          background=args.background, noise_sigma=args.noise, shot_noise=args.shot_noise,
                          bits=args.bits or (16 if args.radiometry else 8),
                          detection_threshold=args.detection_threshold, response=response)
    scene = SceneConfig(altitude_m=args.altitude, max_scan_angle_deg=args.max_scan_angle or 20.0,
                        canopy_cover=args.canopy_cover, roof_fraction=args.roof_fraction,
                        weak_echo_fraction=args.weak_fraction, radiometry=args.radiometry,
                        # the climb spans the flight, whatever its length
                        altitude_change_m=args.altitude_change if args.radiometry else 0.0,
                        altitude_change_s=args.pulses / SceneConfig.pulse_rate_hz,
                        beam_divergence_mrad=args.beam_divergence_mrad, patch_reflectance=args.patch_reflectance)
    start = time.perf_counter()
    rasters = []
    if args.scene == "forest":
        from fwcore.studies.forest import ForestConfig, forest_flight_scene
        from fwcore.studies.forest_truth import write_forest_flight

        scene = dataclasses.replace(forest_flight_scene(), altitude_m=args.altitude,
                                    max_scan_angle_deg=args.max_scan_angle or forest_flight_scene().max_scan_angle_deg)
        flight, rasters = write_forest_flight(args.output, args.pulses, sensor, scene, ForestConfig(), args.seed,
                                              args.format)
    else:
        flight = write_flight(args.output, args.pulses, sensor, scene, args.seed, args.format)
    print(f"wrote {flight.las} ({args.format}, {sensor.bits}-bit): {flight.n_pulses} pulses, {flight.n_returns} "
          f"system returns; {flight.truth}: {flight.n_echoes} true echoes; {flight.trajectory.name}"
          f"{'; ' + flight.calibration.name if flight.calibration else ''}"
          f"{''.join('; ' + p.name for p in rasters)}; {time.perf_counter() - start:.1f} s")
    return 0


def _evaluate(args: argparse.Namespace) -> int:
    from fwcore.studies.comparison import markdown_table, write_csv
    from fwcore.studies.evaluate import EVALUATION_COLUMNS, evaluate_runs

    from pipeline.outputs import read_run
    for folder in args.results:  # an interrupted run's tables would read as a poor method
        read_run(folder)
    if args.output:
        output = check_suffix("fwl evaluate", args.output, (".md", ".csv"), "a table (Markdown or CSV)")
        first = "Echoes matched within" if output.suffix.lower() == ".md" else EVALUATION_COLUMNS[0][0] + ","
        claim_files("fwl evaluate", [output], lambda p: first_line_is(p, first), args.overwrite)
    _check_shares_pulses(args.results, args.truth)
    rows = evaluate_runs(args.results, args.truth, args.match_ps)
    table = markdown_table(rows, EVALUATION_COLUMNS)
    print(table, end="")
    if args.output:
        with folder_lock(output.parent, "fwl evaluate"):
            if output.suffix.lower() == ".csv":
                write_csv(output, rows)
            else:
                output.write_text(f"Echoes matched within {args.match_ps:g} ps against {args.truth}\n\n{table}")
        print(f"wrote {output}")
    return 0


def _compact(args: argparse.Namespace) -> int:
    from pipeline.compact import compact_run

    sizes = {k: v for k, v in (("tile_rows", args.tile_rows), ("row_group_rows", args.row_group_rows)) if v}
    if not Path(args.run_dir).is_dir():  # named as compact_run names it, without making it
        raise FileNotFoundError(f"{args.run_dir}: no such folder")
    with folder_lock(args.run_dir, "fwl compact"):
        done = compact_run(args.run_dir, say=print, **sizes)
    print(f"fwl compact: {args.run_dir}: echoes/ holds {done['tiles']} tiles, {done['echoes']:,} echoes")
    return 0


def _check_shares_pulses(results: list[str], truth: str) -> None:
    """A run and a truth of different flights share no pulse: their table would read as a method that found
    nothing (0.000 and nan). Refused, naming both."""
    import pyarrow.compute as pc
    import pyarrow.dataset as ds
    import pyarrow.parquet as pq

    from pipeline.layout import PULSES

    true_pulses = pq.read_table(truth, columns=["pulse_id"]).column("pulse_id").combine_chunks().unique()
    for folder in results:
        pulses = ds.dataset(str(Path(folder) / PULSES), format="parquet").to_table(columns=["pulse_id"])
        if not pc.any(pc.is_in(pulses.column("pulse_id"), value_set=true_pulses)).as_py():
            raise ValueError(f"fwl evaluate: {folder} shares no pulse with {truth} ({pulses.num_rows} pulses "
                             f"decomposed, {len(true_pulses)} in the truth): the truth of another flight?")


def _info(args: argparse.Namespace) -> int:
    """`fwl info FILE...`: headers and indexes of full-waveform files, never their samples."""
    import json

    from fwcore.io import describe_file
    from fwcore.io.info import format_info
    from fwcore.instrument.measure import measure_input_response

    described, failed = [], 0
    for path in args.files:
        try:
            described.append(describe_file(path))
        except (ValueError, OSError) as err:
            failed += 1
            described.append({"file": path, "error": str(err)})
            if not args.json:
                print(f"fwl: error: {err}", file=sys.stderr)
            continue
        if args.system_response:  # reads the file's first records' samples, as fwl run --model system does
            response = measure_input_response(path)
            described[-1]["system_response"] = response.to_dict() if response else None
        if not args.json:
            print(format_info(described[-1]))
            if args.system_response:
                print(_response_line(described[-1]["system_response"]))
    if args.json:
        print(json.dumps(described if len(described) > 1 else described[0], indent=2, default=str))
    return 2 if failed else 0


def _response_line(response: dict | None) -> str:
    from fwcore.instrument.response import SystemResponse

    if response is None:
        return "  system response: too few strong single returns to measure it"
    r = SystemResponse.from_dict(response)
    delay, height = r.afterpulse()
    after = (f", afterpulse {delay / 1000:.1f} ns behind the peak at {100 * height:.1f}%" if height >= 0.01
             else ", no afterpulse above 1%")
    return f"  system response: FWHM {r.fwhm_ps / 1000:.2f} ns{after}; from {r.source}"


def _grid(args: argparse.Namespace, beam_args: list[str]) -> int:
    from pipeline.grid import grid_run
    from pipeline.layout import GRID_DIR
    from pipeline.options import check_beam_args

    check_beam_args(beam_args)
    if not Path(args.run_dir).is_dir():  # named as grid_run names it, without making it
        raise FileNotFoundError(f"{args.run_dir}: no such folder")
    # the folders it writes: --output (or the run's own grid/), and the run (--classify's classes, the forest
    # maps' tiles under RUN/.forest-maps)
    with folder_lock(args.output or args.run_dir, "fwl grid"), folder_lock(args.run_dir, "fwl grid"):
        summary = grid_run(args.run_dir, args.cell, args.output, args.crs, args.bin_height, args.classify,
                           beam_args, args.resume)
    print(f"fwl grid: {summary['echoes']:,} kept echoes in {summary['cells_with_echoes']:,} of "
          f"{summary['width']} x {summary['height']} cells of {summary['cell_m']:g} {_horizontal_unit(summary['crs'])}; "
          f"{summary['bins']} height bins "
          f"of {summary['bin_height_m']:g} m; CRS: {summary['crs_source']}; wrote {', '.join(summary['files'])} to "
          f"{args.output or Path(args.run_dir) / GRID_DIR}")
    return 0


def _view(args: argparse.Namespace) -> int:
    import secrets
    import webbrowser

    from pipeline.view import make_server, url_of
    from pipeline.view.server import is_loopback

    token = args.token
    if not is_loopback(args.host):  # open to the network on purpose only: say so, and ask for a token
        token = token or secrets.token_urlsafe(24)
        print(f"fwl view: WARNING: listening on {args.host}, not this machine alone: anyone who can reach it and "
              f"has the token can read the served folders and start decompositions", file=sys.stderr, flush=True)
    try:
        server = make_server(args.paths or ["."], args.host, args.port, args.runs_dir, token=token)
    except OSError as err:  # the port is taken, or the address is not this machine's
        if isinstance(err, FileNotFoundError):
            raise
        raise ValueError(f"cannot listen on {args.host}:{args.port}: {err.strerror or err}; "
                         f"choose another --port (0 picks a free one)") from None
    url = url_of(server)
    print(f"fwl view: serving {', '.join(args.paths or ['.'])} at {url} (Ctrl-C to stop)", flush=True)
    if not args.no_browser:
        webbrowser.open(url)
    try:
        server.serve_forever()
    except KeyboardInterrupt:
        pass
    finally:
        server.viewer.jobs.stop_all()
        server.server_close()
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="fwl", description="Full-waveform LiDAR decomposition")
    parser.add_argument("--version", action="version", version=f"fwl {fwcore.__version__}")
    sub = parser.add_subparsers(dest="command", required=True)
    _add_decompose_csv(sub)
    _add_run(sub)
    _add_watch(sub)
    _add_compare(sub)
    _add_simulate(sub)
    _add_evaluate(sub)
    _add_compact(sub)
    _add_info(sub)
    _add_classify(sub)
    _add_footprints(sub)
    _add_grid(sub)
    _add_view(sub)
    return parser


def _add_decompose_csv(sub) -> None:
    from fwcore.io.neon import NEON_SAMPLE_SPACING_PS

    p = sub.add_parser("decompose-csv", help="decompose waveforms of a NEON-layout CSV into a Parquet echo table")
    p.add_argument("input", help="CSV with columns waveform_id, n_samples, s0, s1, ...")
    p.add_argument("--output", required=True, help="echo table (.parquet); waveforms go beside it")
    p.add_argument("--outgoing", help="CSV of outgoing pulses (same layout): measures the system pulse FWHM")
    p.add_argument("--sample-spacing-ps", dest="sample_spacing_ps", type=float, default=NEON_SAMPLE_SPACING_PS)
    p.add_argument("--threads", type=int, help="numba threads (default: all cores)")
    p.add_argument("--overwrite", action="store_true",
                   help="replace the output files even if not written by an earlier fwl decompose-csv "
                        "(refused otherwise)")
    _add_method_options(p)
    p.set_defaults(handler=_decompose_csv)


def _add_run(sub) -> None:
    said = "decompose full-waveform LAS/LAZ and PulseWaves files with the Beam pipeline"
    r = sub.add_parser("run", help=said, description=said[0].upper() + said[1:] + ".", allow_abbrev=False,
                       epilog="Any other option must be a Beam pipeline option (--runner, --dask_client_address, ...); "
                              "the default runner is the DirectRunner with 2 worker processes. Exit codes: 0 all "
                              "decomposed, 3 some inputs or pulses rejected (see DIR/rejected/), 4 nothing decomposed, "
                              "5 stopped by a fault of the machine (a full disk, no permission, an I/O error, no "
                              "memory: fix it, then --resume), 2 usage error (nothing touched; also when another "
                              "command is writing DIR), 130 interrupted.")
    r.add_argument("inputs", nargs="*", help="LAS/LAZ or PulseWaves (.pls) files, glob patterns or folders "
                                              "(their *.las, *.laz, *.pls); "
                                             "default: the bundled Leica sample")
    r.add_argument("--version", action="version", version=f"fwl {fwcore.__version__}")
    r.add_argument("--resume", action="store_true",
                   help="go on with the interrupted run in --output (same inputs and options): keep every range it "
                        "finished, run the rest; a changed input or option is refused")
    from pipeline.options import FwlOptions

    FwlOptions._add_argparse_args(r)
    r.set_defaults(handler=_run)


def _add_watch(sub) -> None:
    w = sub.add_parser("watch", help="process the full-waveform files that land in a folder, each once, as they "
                                     "become complete", allow_abbrev=False,
                       epilog="Run options and Beam pipeline options are those of fwl run; each batch of new files "
                              "is an fwl run into --output, which grows file by file. Ctrl-C stops (exit 0; 130 when "
                              "it interrupts a batch, which a restart resumes).")
    w.add_argument("folder", help="the folder where flight lines land (its *.las, *.laz, *.pls; not recursive)")
    w.add_argument("--poll", type=float, default=5.0, help="seconds between looks at the folder (default 5)")
    w.add_argument("--once", action="store_true",
                   help="look twice, process what is complete, and exit (for cron and scripts)")
    from pipeline.options import FwlOptions

    FwlOptions._add_argparse_args(w)
    w.set_defaults(handler=_watch)


def _add_compare(sub) -> None:
    c = sub.add_parser("compare", help="compare optimizers on a LAS/LAZ or PulseWaves file or a NEON CSV: tables "
                                       "and figures")
    c.add_argument("input", help="full-waveform LAS/LAZ or PulseWaves (.pls) file, or a NEON-layout CSV")
    c.add_argument("--optimizers", default=",".join(o.value for o in Optimizer),
                   help="comma-separated (default: all)")
    c.add_argument("--model", dest="models", default="generalized",
                   help="comma-separated models: system, generalized, gaussian")
    c.add_argument("--limit", type=int, help="the first N waveforms only")
    c.add_argument("--pulses", help="comma-separated pulse ids to plot (default: the 3 most complex)")
    c.add_argument("--distance", type=float, default=0.5, help="point match distance, metres (default 0.5)")
    c.add_argument("--budget", action="store_true", help="also run the evaluation budget study")
    c.add_argument("--threads", type=int, default=1, help="numba threads (default 1: per-core speeds)")
    c.add_argument("--outgoing", help="CSV input: outgoing pulses CSV that measures the system pulse FWHM")
    c.add_argument("--output", required=True, help="output directory")
    c.add_argument("--overwrite", action="store_true",
                   help="replace files in --output even if not written by an earlier fwl compare (refused otherwise)")
    _add_method_options(c, compare=True)
    c.set_defaults(handler=_compare)


def _add_simulate(sub) -> None:
    s = sub.add_parser("simulate", help="write a synthetic full-waveform flight and the truth of its echoes")
    s.add_argument("--pulses", type=int, required=True)
    s.add_argument("--output", required=True, help="FILE.las; the truth goes to FILE.truth.parquet")
    s.add_argument("--format", default="las13-wdp", choices=["las13-wdp", "las14-internal"])
    s.add_argument("--bits", type=int, choices=[8, 16], help="digitizer bits (default 8; 16 with --radiometry)")
    s.add_argument("--seed", type=int, default=0)
    s.add_argument("--overwrite", action="store_true",
                   help="replace the output files even if not written by an earlier fwl simulate (refused otherwise)")
    sensor = s.add_argument_group("sensor")
    sensor.add_argument("--pulse-fwhm-ps", dest="pulse_fwhm_ps", type=float, default=4000.0)
    sensor.add_argument("--sample-spacing-ps", dest="sample_spacing_ps", type=float,
                        help="default 1000; with --sensor-response leica 2000 (its digitizer's)")
    # the simulated sensor's own response; fwl run's --system-response overrides what a file's pulse is measured as
    sensor.add_argument("--sensor-response", dest="sensor_response",
                        help="echoes of an instrument's response broadened by their targets: gaussian (of "
                             "--pulse-fwhm-ps), leica, riegl (measured, shipped) or a response file; default: the "
                             "method's generalized Gaussians")
    sensor.add_argument("--system-response", dest="sensor_response", action=_Renamed, help=argparse.SUPPRESS)
    sensor.add_argument("--samples", type=int, help="samples per packet (default 200; 360 with --scene forest)")
    sensor.add_argument("--gain", type=float, default=0.01, help="digitizer gain, volts per DN")
    sensor.add_argument("--offset", type=float, default=0.0, help="digitizer offset, volts")
    sensor.add_argument("--background", type=float, default=12.0, help="DN")
    sensor.add_argument("--noise", type=float, default=1.5, help="Gaussian noise sigma, DN")
    sensor.add_argument("--shot-noise", dest="shot_noise", type=float, default=0.05,
                        help="signal-dependent noise: variance per DN of signal")
    sensor.add_argument("--detection-threshold", dest="detection_threshold", type=float, default=6.0,
                        help="the online detector's threshold, x noise sigma")
    scene = s.add_argument_group("scene")
    scene.add_argument("--altitude", type=float, default=500.0, help="metres above the terrain")
    scene.add_argument("--scene", choices=["default", "forest"], default="default",
                       help="default: echoes drawn pulse by pulse over rolling terrain; forest: a coherent forest "
                            "(terrain with a break of slope and a ditch, crowns, a clearing, buildings) and its "
                            "truth as 1 m GeoTIFFs (FILE.truth-dtm/chm/cover/pai.tif)")
    scene.add_argument("--max-scan-angle", dest="max_scan_angle", type=float,
                       help="degrees (default 20; 12 with --scene forest)")
    scene.add_argument("--canopy-cover", dest="canopy_cover", type=float, default=0.45)
    scene.add_argument("--roof-fraction", dest="roof_fraction", type=float, default=0.12)
    scene.add_argument("--weak-fraction", dest="weak_fraction", type=float, default=0.15,
                       help="fraction of vegetation echoes near the noise floor")
    radar = s.add_argument_group("radiometry")
    radar.add_argument("--radiometry", action="store_true",
                       help="surfaces of known reflectance, echo energies by the radar equation, a climbing flight, "
                            "a calibration patch (FILE.calibration.json)")
    radar.add_argument("--altitude-change", dest="altitude_change", type=float, default=300.0,
                       help="metres the flight climbs from start to end (default 300)")
    radar.add_argument("--beam-divergence-mrad", dest="beam_divergence_mrad", type=float, default=0.5)
    radar.add_argument("--patch-reflectance", dest="patch_reflectance", type=float, default=0.25,
                       help="the calibration patch's diffuse reflectance (default 0.25)")
    s.set_defaults(handler=_simulate)


def _add_evaluate(sub) -> None:
    e = sub.add_parser("evaluate", help="accuracy of fwl run outputs against a simulated flight's truth")
    e.add_argument("results", nargs="+", help="fwl run output directories")
    e.add_argument("--truth", required=True, help="FILE.truth.parquet from fwl simulate")
    e.add_argument("--match-ps", dest="match_ps", type=float, default=1000.0,
                   help="a true and a decomposed echo match within this time (default 1000 ps)")
    e.add_argument("--output", help="write the table (.md, or .csv)")
    e.add_argument("--overwrite", action="store_true",
                   help="replace --output even if not written by an earlier fwl evaluate (refused otherwise)")
    e.set_defaults(handler=_evaluate)


def _add_compact(sub) -> None:
    k = sub.add_parser("compact", help="rewrite a finished run's echo parts as spatial tiles (GeoParquet in Hilbert "
                                       "order) for box queries; a killed compact is rerun")
    k.add_argument("run_dir", metavar="RUN_DIR", help="a finished fwl run's output folder")
    k.add_argument("--tile-rows", dest="tile_rows", type=int, help="echoes per tile (default 1,000,000)")
    k.add_argument("--row-group-rows", dest="row_group_rows", type=int,
                   help="echoes per row group (default 8192)")
    k.set_defaults(handler=_compact)


def _add_info(sub) -> None:
    i = sub.add_parser("info", help="format, counts, descriptors and their use, CRS, bounds and times of "
                                    "full-waveform files (LAS/LAZ, PulseWaves), from headers and indexes only")
    i.add_argument("files", nargs="+", help="LAS/LAZ or PulseWaves (.pls) files")
    i.add_argument("--json", action="store_true", help="print JSON (a list for several files)")
    i.add_argument("--system-response", dest="system_response", action="store_true",
                   help="also measure the instrument's response on the file's first records, as fwl run --model "
                        "system does (reads samples); --json gives the JSON --system-response FILE accepts")
    i.set_defaults(handler=_info)


def _add_grid(sub) -> None:
    g = sub.add_parser("grid", help="maps of a run's kept echoes as Cloud Optimized GeoTIFFs: highest and lowest "
                                    "echo, echo count, mean reflectance (or amplitude), vertical energy profile",
                       epilog=TILED_EPILOG)
    g.add_argument("run_dir", metavar="RUN_DIR", help="a finished fwl run's output folder (with its echo table)")
    g.add_argument("--cell", type=float, required=True, help="cell size, in the CRS's units (metres)")
    g.add_argument("--output", help="folder for the GeoTIFFs: new, empty or an earlier fwl grid's (default: the run's "
                                    "own grid/ folder, where fwl view finds them)")
    g.add_argument("--crs", help="the CRS to declare (e.g. EPSG:25832) where the run's inputs name none")
    g.add_argument("--bin-height", dest="bin_height", type=float, default=1.0,
                   help="height of the profile's bins above each cell's lowest echo, and of pavd.tif's above the "
                        "terrain (default 1 m)")
    g.add_argument("--classify", action="store_true",
                   help="classify the run's echoes first (as fwl classify) if they are not yet: the forest's maps "
                        "(dtm, dsm, chm, cover, pai, pavd, rh98, rh50) need the classes")
    g.add_argument("--resume", action="store_true",
                   help="go on with an interrupted fwl grid (and its --classify): the tiles it finished are kept")
    g.set_defaults(handler=_grid)


def _horizontal_unit(crs_wkt: str | None) -> str:
    """The unit of a CRS's first axis, for messages (a GEDI run's cells are degrees); metres without a CRS."""
    import pyproj

    if not crs_wkt:
        return "m"
    unit = pyproj.CRS.from_wkt(crs_wkt).axis_info[0].unit_name
    return {"metre": "m", "degree": "degrees"}.get(unit, unit)


def _footprints(args: argparse.Namespace, beam_args: list[str]) -> int:
    from fwcore.metrics.biomass import check_stratum
    from pipeline.footprints import footprints_run
    from pipeline.options import check_beam_args

    check_beam_args(beam_args)
    if not Path(args.run_dir).is_dir():
        raise FileNotFoundError(f"{args.run_dir}: no such folder")
    with folder_lock(args.run_dir, "fwl footprints"):  # its work folder is in the run
        path = footprints_run(args.run_dir, args.spacing, args.gedi, args.output, args.crs, beam_args=beam_args,
                              resume=args.resume,
                              stratum=check_stratum(args.stratum) if args.stratum else None)
    import pyarrow.parquet as pq

    table = pq.read_table(path, columns=["reason", "agbd_reason"])
    rows, biomass = table.column("reason").to_pylist(), table.column("agbd_reason").to_pylist()
    why = next((r for r in biomass if r), "")  # the first reason a footprint has no agbd
    print(f"fwl footprints: {len(rows):,} footprints, {sum(r == '' for r in rows):,} measured, "
          f"{sum(r == '' for r in biomass):,} with agbd{f' (else: {why})' if why else ''} -> {path}")
    return 0


def _add_footprints(sub) -> None:
    f = sub.add_parser("footprints", help="what GEDI would record over a run: 25 m footprints' waveforms built from "
                                          "the airborne echoes, and their GEDI metrics, as GeoParquet",
                       epilog=TILED_EPILOG)
    f.add_argument("run_dir", metavar="RUN_DIR", help="a finished fwl run's output folder (with its echo table)")
    where = f.add_mutually_exclusive_group(required=True)
    where.add_argument("--gedi", help="a GEDI L2A granule (.h5): footprints at its shots over the run")
    where.add_argument("--spacing", type=float, help="footprints on a square grid of this spacing, metres")
    f.add_argument("--output", help="the GeoParquet file (default RUN_DIR/footprints.parquet)")
    f.add_argument("--crs", help="the run's CRS where its inputs name none (to place GEDI's shots)")
    f.add_argument("--stratum", help=STRATUM_HELP)
    f.add_argument("--resume", action="store_true",
                   help="go on with an interrupted fwl footprints: the bands of footprints it finished are kept")
    f.set_defaults(handler=_footprints)


def _classify(args: argparse.Namespace, beam_args: list[str]) -> int:
    from fwcore.terrain.ground import GroundConfig
    from pipeline.classify import classify_run, summary_line
    from pipeline.options import check_beam_args

    config = GroundConfig(cloth_resolution=args.cloth_resolution, rigidness=args.rigidness)
    check_beam_args(beam_args)  # a mistyped runner option stops here, before the run is touched
    if not Path(args.run_dir).is_dir():
        raise FileNotFoundError(f"{args.run_dir}: no such folder")
    with folder_lock(args.run_dir, "fwl classify"):  # it rewrites the run's echo table and point clouds
        print(summary_line(classify_run(args.run_dir, args.tile, args.overlap, config, beam_args, args.resume)))
    return 0


TILED_EPILOG = ("Any other option must be a Beam pipeline option (--runner, --direct_num_workers, "
                "--dask_client_address, ...): the tiles run on the runners of fwl run, by default the DirectRunner with "
                "2 worker processes (docs/cluster.md).")


def _add_classify(sub) -> None:
    from fwcore.terrain.tiles import DEFAULT_OVERLAP_M, DEFAULT_TILE_M

    c = sub.add_parser("classify", help="classify a run's kept echoes (ASPRS ground, building, vegetation by height) "
                                        "and give each its height above the terrain, in the run's echo table",
                       epilog=TILED_EPILOG)
    c.add_argument("run_dir", metavar="RUN_DIR", help="a finished fwl run's output folder (with its echo table)")
    c.add_argument("--tile", type=float, default=DEFAULT_TILE_M, help="tile size, metres (default %(default)g)")
    c.add_argument("--overlap", type=float, default=DEFAULT_OVERLAP_M,
                   help="margin each tile is processed with, metres (default %(default)g)")
    c.add_argument("--cloth-resolution", dest="cloth_resolution", type=float, default=1.0,
                   help="the cloth simulation filter's grid, metres (default 1)")
    c.add_argument("--rigidness", type=int, choices=[1, 2, 3], default=2,
                   help="the cloth's rigidness: 1 steep terrain, 2 moderate slopes, 3 flat (default 2)")
    c.add_argument("--resume", action="store_true",
                   help="go on with an interrupted fwl classify of the run: the tiles it finished are kept")
    c.set_defaults(handler=_classify)


def _add_view(sub) -> None:
    v = sub.add_parser("view", help="a local web viewer of runs and their pulses (offline)")
    v.add_argument("paths", nargs="*", metavar="RUN_DIR|FOLDER|INPUT",
                   help="run folders, folders to search for runs and inputs, or .las/.laz/.pls inputs (default .)")
    v.add_argument("--host", default="127.0.0.1",
                   help="address to listen on (default 127.0.0.1); any other asks for a token (printed once)")
    v.add_argument("--token", default=None,
                   help="the token every API call must carry (default: none on 127.0.0.1, a random one otherwise)")
    v.add_argument("--port", type=int, default=8050, help="port (default 8050; 0 picks a free one)")
    v.add_argument("--runs-dir", dest="runs_dir", default="out/view",
                   help="where runs of picked inputs are written (default out/view)")
    v.add_argument("--no-browser", dest="no_browser", action="store_true", help="do not open a browser")
    v.set_defaults(handler=_view)


def _parser_flags(parser: argparse.ArgumentParser, command: str) -> list[str]:
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction)).choices[command]
    return [s for a in sub._actions for s in a.option_strings]


def main(argv: list[str] | None = None) -> int:
    quiet_imports()  # before Beam is imported: its import-time warnings are not the user's business
    from pipeline.options import unknown_option_error

    parser = build_parser()
    args, rest = parser.parse_known_args(argv)
    args.argv = list(sys.argv[1:] if argv is None else argv)
    try:
        if args.command in ("run", "watch", "classify", "grid", "footprints"):  # these take Beam's options
            return args.handler(args, rest)
        if rest:
            raise unknown_option_error(rest, _parser_flags(parser, args.command))
        return args.handler(args)
    except (ValueError, FileNotFoundError) as err:  # OptionError is a ValueError
        print(f"fwl: error: {err}", file=sys.stderr)
        return 2
    except (OSError, MemoryError) as err:  # a full disk, no permission...: what to fix, in one line
        fault = machine_fault(err, WRITING, getattr(args, "output", None) or ".", f"fwl {args.command}")
        if fault is None:
            raise
        print(f"fwl: error: {fault.said()}: {fault.remedy()}, then run the command again", file=sys.stderr)
        return 5  # pipeline.summary.EXIT_MACHINE (pipeline.summary imports Beam)


def entry() -> None:
    """The `fwl` command: main, then the process leaves without the interpreter's teardown (numba's, Beam's and
    gRPC's modules and threads), its logs and output flushed (pipeline.worker_exit.leave_now)."""
    code = main()
    from pipeline.worker_exit import leave_now

    leave_now(code if isinstance(code, int) else 0)


if __name__ == "__main__":
    entry()
