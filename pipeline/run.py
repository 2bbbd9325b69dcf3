"""Build and run the pipeline's jobs over the inputs into a claimed output folder.

    validate options and inputs (with radiometry: each trajectory checked, C_cal found on a reference patch)
    -> take the output folder (pipeline.outputs) -> plan, ranges and files jobs
    -> run.json (pipeline.summary, which also says the exit codes)

The three jobs: the plan job plans each input on a worker; the ranges job decomposes each range
(transforms.DecomposeFlight); the files job assembles each input's point cloud and MCAP from its ranges'
parts (transforms.AssembleFiles). A small run's jobs run in the driver's process (`Jobs`). A fault of the
machine noted by a worker stops the run (RunStopped) for a resume once it is fixed.
"""

from __future__ import annotations

import contextlib
import dataclasses
import logging
import signal
import threading
import time
from pathlib import Path

import apache_beam as beam
from apache_beam.options.pipeline_options import DirectOptions, PipelineOptions, SetupOptions, StandardOptions

import fwcore
from fwcore.engine.config import DecompositionConfig, Model
from fwcore.instrument.pulse import PulseOverrides
from fwcore.radiometry.flight import PatchFile, calibrate_on_reference, check_flight, file_radiometry
from fwcore.radiometry.equations import RadiometryConfig, RadiometryError
from fwcore.io.crs import GIVEN, crs_name, parse_crs
from pipeline.forest_settings import ForestSettings
from pipeline.faults import RunStopped, clear_faults, faults_in, noted_faults, output_fault
from pipeline.layout import LOGS, PARTS, file_rejected, plan_path, progress_mark
from pipeline.lock import folder_lock
from pipeline.logs import log_to_file, watched_logs
from pipeline.marks import counts_from_marks, range_is_complete, remove_range_files
from pipeline.options import check_beam_args, check_formats, is_dask, pipeline_runner, runner_given
from pipeline.outputs import (InputNames, add_to_output_folder, input_identity, mark_inputs_done, match_inputs,
                              read_manifest, read_run, remove_input_outputs, remove_partial_files, resume_output_folder,
                              take_output_folder)
from pipeline.assemble import written_parts
from pipeline.plan import FilePlan, InputToPlan, inputs_to_plan, planned_pulses, read_plans
from pipeline.progress import ProgressBar
from pipeline.rejections import write_file_rejection
from pipeline.schedule import longest_first
from pipeline.summary import JobsDone, beam_metrics, planned_of, summarise
from pipeline.timing import Laps, log_timing
from pipeline.handoff import hand_over, withdraw
from pipeline.transforms import (AssembleFiles, AwaitRanges, DecomposeFlight, PlanFiles, assemble_file_or_fault,
                                 plan_into_parts)

__all__ = ["Jobs", "RunStopped", "check_run_arguments", "run", "run_jobs", "run_settings"]

LOG = logging.getLogger(__name__)  # the driver's: to driver.log and, for warnings, the terminal
BUNDLED_SAMPLE = Path(__file__).resolve().parents[1] / "examples" / "data" / "leica_als" / "leica_a.las"


INTERRUPTED = threading.Event()  # set on Ctrl-C: a job run in this process fails with Beam's error, not with it


@contextlib.contextmanager
def _quiet_after_interrupt():
    """On Ctrl-C, Beam's teardown (its logged errors, its threads' tracebacks) goes unsaid: the caller
    says "interrupted" once. Only the main thread can take signals; elsewhere nothing changes."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def interrupted(signum, frame):
        INTERRUPTED.set()
        logging.disable(logging.CRITICAL)  # for the rest of this process, which is ending
        threading.excepthook = lambda args: None
        raise KeyboardInterrupt

    INTERRUPTED.clear()
    previous = signal.signal(signal.SIGINT, interrupted)
    try:
        yield
    except Exception as err:
        if INTERRUPTED.is_set():  # Beam wraps an interruption inside a step as its own error: still one
            raise KeyboardInterrupt from err
        raise
    finally:
        signal.signal(signal.SIGINT, previous)


def check_run_arguments(formats, limit: int | None, points_per_range: int) -> frozenset[str]:
    formats = check_formats(formats)
    if not isinstance(points_per_range, int) or points_per_range < 1:
        raise ValueError(f"--points-per-range must be a whole number >= 1, not {points_per_range}")
    if limit is not None and (not isinstance(limit, int) or limit < 1):
        raise ValueError(f"--limit must be a whole number >= 1, not {limit}")
    return formats


def _runner_name(options, in_process: bool = False, threads: bool = False) -> str:
    runner = options.view_as(StandardOptions).runner
    name = runner.rsplit(".", 1)[-1] if isinstance(runner, str) else type(runner).__name__
    if name == "DirectRunner" and in_process:
        return "DirectRunner, in this process"
    if name == "DirectRunner":
        workers = options.view_as(DirectOptions).direct_num_workers
        threaded = threads or options.view_as(DirectOptions).direct_running_mode == "multi_threading"
        return f"DirectRunner, {workers} worker threads" if threaded else f"DirectRunner, {workers} workers"
    return name


IN_PROCESS_PULSES = 4000  # a run of this many pulses or fewer decomposes and assembles in the driver's process
IN_PROCESS_BYTES = 16 << 20  # inputs of this many bytes or fewer (their point records) are planned there
# inputs of this many point records or fewer run the ranges' workers as threads of the driver's process (threaded)
THREADED_POINTS = 300_000


class Jobs:
    """The run's Beam jobs, each over a first collection of n elements, on the configured runner.

    The Dask runner partitions a job's first collection into bags of 128 elements and treats Reshuffle as a
    no-op, so a few dozen ranges (or files) would run in one partition on one worker: each gets its own
    partition, unless the command line partitions them itself.

    Under the default DirectRunner (`small_in_process`: the command line chose no runner), a small job runs
    in the driver's process: two worker processes take 2-3 s to start (Beam, numba's kernels), more than
    the few seconds of work they would share (the shared Leica folder: 11.6-16.7 s with them, 2.9-4.1x one
    file). Results do not depend on where a job runs.
    """

    def __init__(self, options, small_in_process: bool = False):
        self.options = options
        self.small_in_process = small_in_process
        self.dask = is_dask(options)
        if self.dask:
            from apache_beam.runners.dask.dask_runner import DaskOptions
            bags = options.view_as(DaskOptions)
            self.partition_each = bags.npartitions is None and bags.partition_size is None
        runner = options.view_as(StandardOptions).runner
        self.direct_processes = (isinstance(runner, str) and runner.rsplit(".", 1)[-1] == "DirectRunner"
                                 and options.view_as(DirectOptions).direct_running_mode == "multi_processing")

    def threaded(self, paths: list[str]) -> bool:
        """Whether the ranges' job runs its workers as threads of this process: under the default runner, when the
        inputs hold at most THREADED_POINTS point records. Two worker processes each start Beam, our modules and
        numba's kernels anew (3-4 s of the two cores on the RIEGL-like line's 170,130 points) before their first
        range; threads begin at once and lose less than that to the GIL (docs/benchmarks.md, issue 60's fifth
        pass)."""
        return (self.small_in_process and self.direct_processes
                and sum(_records(p) for p in paths) <= THREADED_POINTS)

    def in_process(self, n: int, small: bool = False) -> bool:
        """Whether a job of n elements runs in this process: one element, or a small job (`small`) when the
        runner is the default."""
        return self.direct_processes and (n == 1 or (small and self.small_in_process))

    def run(self, n: int, build, small: bool = False, per_partition: int = 1, threads: bool = False):
        """One job: `build(pipeline)` adds its transforms; waits for its end. On Dask, unless the command line
        partitions, each bag partition holds `per_partition` consecutive elements. With `threads` (threaded), the
        DirectRunner's workers are threads of this process."""
        if self.dask and self.partition_each:
            from apache_beam.runners.dask.dask_runner import DaskOptions
            self.options.view_as(DaskOptions).npartitions = max(1, -(-n // max(1, per_partition)))
        if not self.in_process(n, small):
            return _run_job(_in_threads(self.options) if threads else self.options, build)
        try:
            return _run_job(_in_process(self.options), build)
        except Exception as err:  # Beam wraps the KeyboardInterrupt raised in its bundle: an interruption still
            if INTERRUPTED.is_set():
                raise KeyboardInterrupt from err
            raise

    def each(self, items: list, call, build, small: bool = False, per_partition: int = 1) -> None:
        """A job of one plain call an element: where it would run in this process, `call(item)` for each, without
        a Beam pipeline (0.1-0.3 s a job to build and run in memory, for nothing the calls need); elsewhere the
        job `build` makes (run)."""
        if not self.in_process(len(items), small):
            self.run(len(items), build, small, per_partition)
            return
        for item in items:
            call(item)


def _in_process(options):
    """The DirectRunner's options for a job of one element (one file to plan or assemble) or a small one: run in
    this process, where starting worker processes (~2 s each, numba's kernels loaded anew) would cost more than
    the work."""
    single = PipelineOptions.from_dictionary(options.get_all_options(drop_default=True))
    single.view_as(DirectOptions).direct_running_mode = "in_memory"
    single.view_as(DirectOptions).direct_num_workers = 1
    single.view_as(SetupOptions).save_main_session = False
    return single


def _in_threads(options):
    """The DirectRunner's options for a job whose workers (as many as asked) are threads of this process."""
    threaded = PipelineOptions.from_dictionary(options.get_all_options(drop_default=True))
    threaded.view_as(DirectOptions).direct_running_mode = "multi_threading"
    threaded.view_as(SetupOptions).save_main_session = False
    return threaded


def _records(path: str) -> int:
    """An input's point records, from its header; 0 where it cannot be read (its plan rejects it)."""
    from fwcore.io import input_summary

    try:
        return int(input_summary(path).records)
    except Exception:  # noqa: BLE001  any unreadable input: its plan says why
        return 0


def _run_job(options, build) -> object:
    pipeline = beam.Pipeline(runner=pipeline_runner(options), options=options)
    build(pipeline)
    result = pipeline.run()
    result.wait_until_finish()
    if hasattr(result, "client"):  # the Dask runner leaves its client open
        result.client.close()
    return result


def run_settings(config: DecompositionConfig, formats: frozenset[str], limit: int | None, points_per_range: int,
                 laz: bool, radiometry: RadiometryConfig = RadiometryConfig(), crs: str | None = None,
                 overrides: PulseOverrides = PulseOverrides(), forest: ForestSettings = ForestSettings()) -> dict:
    """What makes a run's outputs what they are (not the runner, nor the number of workers; the version of
    fwlidar, whose engine may change them): its fingerprint. A --crs pyproj cannot read is a ValueError here."""
    trajectory = {"trajectory_identity": input_identity(radiometry.trajectory)} if radiometry.trajectory else {}
    given = {"crs": crs} if crs and parse_crs(crs) else {}  # a run without --crs keeps the fingerprint it had
    given.update(forest.fingerprint())  # likewise a run with the forest's defaults
    return {**given, "config": config.to_dict(), "overrides": overrides.to_dict(), "formats": sorted(formats), "limit": limit,
            "points_per_range": points_per_range, "laz": laz, "radiometry": {**radiometry.to_dict(), **trajectory},
            "fwlidar": fwcore.__version__}


def check_radiometry(paths: list[str], radiometry: RadiometryConfig) -> None:
    """Before the folder is touched: the trajectory against each input it serves, and a reference patch's needs
    (an input with ranges and a beam divergence) (fwcore.radiometry.flight). An input that cannot be read is left
    to its plan, which rejects it with the reason."""
    if not (radiometry.trajectory or radiometry.calibration_reference):
        return
    from fwcore.io import input_summary

    files = []
    for path in paths:
        try:
            adjusted = input_summary(path).adjusted_standard_gps_time
        except (OSError, ValueError):
            continue
        files.append(check_flight(path, adjusted, radiometry))
    if radiometry.calibration_reference and files and not any(f.range_source and f.beam_divergence_mrad
                                                              for f in files):
        f = files[0]
        why = f.why_no_range if not f.range_source else (f"{Path(f.path).name}: the file does not record its beam "
                                                         "divergence: give --beam-divergence-mrad")
        raise RadiometryError(f"--calibration-reference needs an input with ranges and a beam divergence: {why}")


def calibrate(plans: dict[str, FilePlan], config: DecompositionConfig, radiometry: RadiometryConfig,
              say) -> tuple[RadiometryConfig, dict | None]:
    """With a reference patch: C_cal from its single returns (before the flight is decomposed), said on the terminal;
    the radiometry the ranges then use, and the calibration for run.json."""
    if radiometry.calibration_reference is None:
        return radiometry, None
    files = [PatchFile(s.path, plan.ranges, config, s.pulse, s.adjusted_standard_gps_time)
             for plan in plans.values() if (s := plan.source) is not None]
    found = calibrate_on_reference(files, radiometry)
    say.write(f"fwl run: calibration constant {found.constant:.6g} from {found.n} single returns of the reference "
              f"patch (robust spread {100 * found.spread:.1f}%)\n")
    say.flush()
    calibrated = dataclasses.replace(radiometry, calibration_constant=found.constant,
                                     calibration_source=f"reference patch ({found.n} single returns)")
    return calibrated, {**found.to_dict(), "source": calibrated.calibration_source}


class EarlyRanges:
    """The ranges' job started in a thread before the plans are made (pipeline.handoff): its worker processes
    start while the driver plans, then take the ranges `finish` hands over, each worker the next unclaimed one as it
    finishes its last (pipeline.handoff.claimed_ranges). Only where its workers are processes
    of this machine (the DirectRunner's) and the ranges' settings are known before the plans (no reference patch
    to calibrate on first)."""

    def __init__(self, options, output: Path, config: DecompositionConfig, formats: frozenset[str],
                 radiometry: RadiometryConfig, forest: ForestSettings = ForestSettings()):
        self.output, self.result, self.error, self.handed = output, None, None, False

        def build(p):
            return _claiming_workers(p, options, output, config, formats, radiometry, forest)
        self.thread = threading.Thread(target=self._run, args=(options, build), name="ranges-job", daemon=True)
        self.thread.start()

    @staticmethod
    def wanted(jobs: "Jobs", paths: list[str], radiometry: RadiometryConfig, threads: bool = False) -> bool:
        """Whether to start the ranges' job early: DirectRunner processes (not `threads`: Jobs.threaded), inputs
        too big to plan in this process."""
        return (jobs.direct_processes and not jobs.dask and not threads and radiometry.calibration_reference is None
                and sum(_size(p) for p in paths) > IN_PROCESS_BYTES)

    def _run(self, options, build) -> None:
        try:
            self.result = _run_job(options, build)
        except BaseException as err:  # noqa: BLE001  raised in the driver's thread by finish
            self.error = err

    def finish(self, tasks: list) -> object:
        """The ranges handed over; the job's result once it ended (its error raised here)."""
        if not self.handed:
            hand_over(self.output, tasks)
            self.handed = True
        self.thread.join()
        withdraw(self.output)
        if self.error is not None:
            raise self.error
        return self.result

    def abandon(self, wait: bool) -> None:
        """No ranges for it (the run stopped before them): the job ends; waited for unless interrupted."""
        if not self.handed:
            hand_over(self.output, [])
            self.handed = True
        if wait:
            self.thread.join()
        withdraw(self.output)


def _workers(options) -> int:
    return max(1, options.view_as(DirectOptions).direct_num_workers)


def _claiming_workers(p, options, output: Path, config: DecompositionConfig, formats: frozenset[str],
                      radiometry: RadiometryConfig, forest: ForestSettings):
    """A job of one element a worker, each claiming the handed-over ranges one at a time as it finishes its last
    (pipeline.handoff.claimed_ranges) and decomposing them."""
    # Create reshuffles its elements itself (one to a worker): a second shuffle was a stage more to start
    return (p | "Workers" >> beam.Create(list(range(_workers(options))))
            | "AwaitRanges" >> beam.ParDo(AwaitRanges(str(output), config))
            # no shuffle: each worker's claims feed its own ranges' DoFn, from the hand-over on
            | "DecomposeFlight" >> DecomposeFlight(config, str(output), formats, spread=False, radiometry=radiometry,
                                                   forest=forest))


def _claimed_in_order(jobs: Jobs, ordered: list, output: Path, config: DecompositionConfig, formats: frozenset[str],
                      radiometry: RadiometryConfig, forest: ForestSettings, small: bool) -> object:
    """The ranges' job on threads, each worker claiming the next of `ordered` (pipeline.schedule.longest_first) as
    it finishes its last (pipeline.handoff), instead of Beam's deal of equal numbers of ranges before any runs."""
    hand_over(output, ordered)
    try:
        return jobs.run(len(ordered), lambda p: _claiming_workers(p, jobs.options, output, config, formats, radiometry,
                                                                  forest), small, threads=True)
    finally:
        withdraw(output)


def _ranges_job(jobs: Jobs, todo: list, early: EarlyRanges | None, threads: bool, small: bool, output: Path,
                config: DecompositionConfig, formats: frozenset[str], radiometry: RadiometryConfig,
                forest: ForestSettings) -> object:
    """The ranges' job: on the early workers, on threaded workers claiming the costliest ranges first, or as Beam
    deals them (Dask's partitions, worker processes, ranges whose cost is not estimated)."""
    # the costliest ranges first, for workers that claim them (never for Dask's partitions)
    ordered = longest_first(todo, config, _workers(jobs.options)) if threads or early else None
    if early:
        return early.finish(ordered or todo)
    if ordered:
        return _claimed_in_order(jobs, ordered, output, config, formats, radiometry, forest, small)
    return jobs.run(len(todo), lambda p: (
        p | "Ranges" >> beam.Create(todo) | "DecomposeFlight" >> DecomposeFlight(
            config, str(output), formats, spread=not jobs.dask, radiometry=radiometry, forest=forest)),
        small, threads=threads)


def plan_files(output: Path, inputs: list[InputToPlan], config: DecompositionConfig, points_per_range: int,
               limit: int | None, jobs: Jobs, threads: bool = False) -> dict[str, FilePlan]:
    """The plan job: each input without a plan yet (a resumed run keeps those it has) planned on a worker (in
    this process where the ranges' workers are its `threads`)."""
    todo = [i for i in inputs if not plan_path(output, i.stem).is_file()]
    if todo:
        small = threads or sum(_size(i.path) for i in todo) <= IN_PROCESS_BYTES
        if jobs.in_process(len(todo), small):
            log_to_file(output)  # as PlanFile's setup: its lines in this process's worker log
        jobs.each(todo, lambda item: plan_into_parts(item, str(output), config, points_per_range, limit),
                  lambda p: (p | "Inputs" >> beam.Create(todo)
                             | "Plan" >> PlanFiles(str(output), config, points_per_range, limit, spread=not jobs.dask)),
                  small)
    return read_plans(output, inputs)


def _size(path: str) -> int:
    try:
        return Path(path).stat().st_size
    except OSError:  # gone, or not a file: its plan rejects it
        return 0


def _models(config: DecompositionConfig, plans: dict[str, FilePlan]) -> str:
    """The run's echo model; under --model auto, what its files got (run.json says why, per file)."""
    chosen = [p.source.pulse.model for p in plans.values() if p.source is not None and p.source.pulse.model]
    if config.model is not Model.AUTO or not chosen:
        return config.model.value
    if len(chosen) == 1:
        return f"auto ({chosen[0]})"
    return "auto (" + ", ".join(f"{m} {chosen.count(m)} files" for m in sorted(set(chosen))) + ")"


def claim_folder(output: Path, paths: list[str], settings: dict, resume: bool, add: bool) -> tuple[InputNames, str]:
    """The output folder taken as the call asks (pipeline.outputs): the names of all its inputs, and how it was
    taken: new, resumed, complete (a resumed run that had finished) or added."""
    identities = {p: input_identity(p) for p in paths}
    if add:
        return add_to_output_folder(output, paths, settings, identities)[0], "added"
    if not resume:
        names = InputNames.of(paths)
        take_output_folder(output, names, paths, settings, identities)
        return names, "new"
    return resume_output_folder(output, paths, settings, identities)


def run(inputs: list[str], output: str | Path, config: DecompositionConfig, formats=("parquet", "las", "mcap"),
        limit: int | None = None, points_per_range: int = 5000, laz: bool = False,
        beam_args: list[str] | None = None, verbose: bool = False, watch: bool = True, resume: bool = False,
        add: bool = False, radiometry: RadiometryConfig = RadiometryConfig(), crs: str | None = None,
        overrides: PulseOverrides = PulseOverrides(), forest: ForestSettings = ForestSettings()) -> dict:
    """Decompose every pulse of the inputs into DIR's outputs; return (and write) the run summary.

    Everything is checked before the output folder is touched; ValueError / FileNotFoundError
    (OutputFolderError for a folder holding what is not ours; ResumeError for a folder this call cannot
    resume or add to; OptionError for a mistyped option) then, and nothing is changed. `resume` goes on with
    the folder's interrupted run of the same inputs and settings, keeping every range it finished; `add`
    (fwl watch) adds the inputs to those the folder holds. With `watch`, a start line and a progress bar go
    to the terminal; logs go to DIR/logs/ (and to the terminal too with `verbose`). `crs` (--crs: an EPSG
    code, WKT or PROJJSON) replaces the CRS the inputs say in every output. `overrides` (--system-pulse-fwhm-ps,
    --system-response, --shape-tolerance, a preset's) is taken instead of what each file's plan would measure.
    `forest` (pipeline.forest_settings): --stratum, the L4A biomass model of large-footprint shots whose land
    cover no L2A granule beside names (an unknown name is a ValueError listing the strata); --l2a-algorithms
    (GEDI only): "selected" (each shot's L2A-selected algorithm, else 1), a number 1..6 (that algorithm for
    every shot) or "all" (also every algorithm's ground_z_aN / rh_aN columns); --pulse-metrics, a small
    footprint's forest metrics from its echoes, or "full" (its waveform's).
    A fault of the machine (pipeline.faults) stops the run with RunStopped naming each cause: no run.json, nothing
    rejected for it, the ranges that finished kept for `resume`. Another command writing the folder (its lock,
    pipeline.lock) is a FolderLockedError, an OutputFolderError.
    """
    formats = check_run_arguments(formats, limit, points_per_range)
    output = Path(output).resolve()
    options = check_beam_args(beam_args or [])
    matched = match_inputs(inputs or [str(BUNDLED_SAMPLE)])
    paths = matched.paths
    forest = forest.checked()
    settings = run_settings(config, formats, limit, points_per_range, laz, radiometry, crs, overrides, forest)
    check_radiometry(paths, radiometry)
    try:
        with folder_lock(output, "fwl watch" if add else "fwl run"):  # one writer: a second is refused (exit 2)
            return _run_claimed(paths, output, config, formats, limit, points_per_range, laz, options, verbose, watch,
                                resume, add, radiometry, crs, overrides, settings, matched.not_taken, beam_args,
                                forest)
    except RunStopped:
        raise
    except Exception as err:
        faults = faults_in(err, output)  # a full disk, no permission, ...: no fault of the data
        if not faults:
            raise
        raise RunStopped(faults, output) from err


def _run_claimed(paths: list[str], output: Path, config: DecompositionConfig, formats: frozenset[str],
                 limit: int | None, points_per_range: int, laz: bool, options, verbose: bool, watch: bool,
                 resume: bool, add: bool, radiometry: RadiometryConfig, crs: str | None, overrides: PulseOverrides,
                 settings: dict, not_taken: list[tuple[str, str]], beam_args: list[str] | None,
                 forest: ForestSettings = ForestSettings()) -> dict:
    """run() once the folder's lock is held: claim it, run the jobs, summarise."""
    names, taken = claim_folder(output, paths, settings, resume, add)  # not_taken: into run.json, said by fwl run
    if taken == "complete":  # its run.json stays as it is
        return {**read_run(output), "taken": taken}
    began = time.perf_counter()
    done = {e["path"] for e in read_manifest(output)["inputs"] if e.get("done")}
    if taken == "resumed" and done >= set(paths):  # killed after its last job, while counting: nothing to redo
        jobs = JobsDone(ranges=None, ranges_reused=None, metrics={}, planned={}, pulses_processed=0)
    else:
        jobs = run_jobs(output, paths, names, config, formats, limit, points_per_range, laz, options, verbose, watch,
                        radiometry, parse_crs(crs) if crs else None, not runner_given(beam_args or []), overrides,
                        forest)
        mark_inputs_done(output, paths, jobs.planned)
    return summarise(output, formats, limit, points_per_range, config, options, time.perf_counter() - began, jobs,
                     taken, radiometry, not_taken, crs, overrides, forest.pulse_metrics)


def run_jobs(output: Path, paths: list[str], names: InputNames, config: DecompositionConfig, formats: frozenset[str],
             limit: int | None, points_per_range: int, laz: bool, options, verbose: bool, watch: bool,
             radiometry: RadiometryConfig = RadiometryConfig(), crs_wkt: str | None = None,
             small_in_process: bool = False, overrides: PulseOverrides = PulseOverrides(),
             forest: ForestSettings = ForestSettings()) -> JobsDone:
    """The three jobs (plan, ranges, files) over the inputs `paths` of the claimed folder, each range finished
    by an earlier attempt kept; the parts of these inputs removed at the end."""
    plans: dict[str, FilePlan] = {}
    result, jobs, calibration, counted, early = None, Jobs(options, small_in_process), None, {}, None
    try:
        with _quiet_after_interrupt(), watched_logs(output, verbose) as (say, terminal):
            clear_faults(output)  # an earlier attempt's notes: a fault that stays is noted again
            threads = jobs.threaded(paths)  # the ranges' workers threads of this process: all jobs run here
            if EarlyRanges.wanted(jobs, paths, radiometry, threads):  # its workers start while the inputs are planned
                early = EarlyRanges(options, output, config, formats, radiometry, forest)
            laps = Laps()
            with laps("plan job"):
                to_plan = inputs_to_plan(paths, names, crs_wkt, overrides, forest.l2a_algorithms)
                plans = plan_files(output, to_plan, config, points_per_range, limit, jobs, threads)
            stop_on_noted_faults(output)  # before a lost plan would read as a rejected input
            _warn_unmeasured(plans)
            ranges_from, no_range = _ranges_from(plans, radiometry)
            radiometry, calibration = calibrate(plans, config, radiometry, say)
            files_rejected = sum(1 for p in plans.values() if p.rejection)
            tasks = [t for p in plans.values() for t in p.tasks]
            reused = {progress_mark(output, t.source.stem, t.start).name for t in tasks if range_is_complete(output, t)}
            todo = [t for t in tasks if progress_mark(output, t.source.stem, t.start).name not in reused]
            for task in todo:
                remove_range_files(output, task)
            total = sum(planned_pulses(t) for t in todo)
            small = sum(planned_pulses(t) for t in tasks) <= IN_PROCESS_PULSES
            if watch:
                said = f" ({files_rejected} rejected)" if files_rejected else ""
                kept = f", {len(reused)} ranges reused" if reused else ""
                method = f"{config.optimizer.value}/{_models(config, plans)}"
                say.write(f"fwl run: {len(paths)} file(s){said}, {total:,} pulses in {len(todo)} ranges{kept} -> "
                          f"{output} ({', '.join(sorted(formats))}); {method}; "
                          f"{_runner_name(options, jobs.in_process(len(todo), small), threads)}; "
                          f"logs in {output / LOGS}\n")
                for why in no_range:  # once per input, and in run.json
                    say.write(f"fwl run: no radiometry: {why}\n")
                crs_said = crs_line(plans)
                if crs_said:
                    say.write(f"fwl run: {crs_said}\n")
                say.flush()
            if todo:
                with ProgressBar(output / PARTS, total, terminal, interactive=None if watch else False,
                                 line_every=60.0 if watch else float("inf"), already=reused):
                    laps.seconds["ranges job began"] = time.time()
                    with laps("ranges job"):
                        result = _ranges_job(jobs, todo, early, threads, small, output, config, formats, radiometry,
                                             forest)
            unfinished = [t for t in todo if not range_is_complete(output, t)]
            if unfinished:  # the machine's faults (noted by the workers), or a worker lost without a word
                stop_on_noted_faults(output, len(unfinished), len(tasks))
            files = written_parts(str(output), tasks, formats)
            if files:  # each file assembled from its parts on disk, the reused ranges' and the new
                with laps("files job"):
                    jobs.each(files, lambda item: assemble_file_or_fault(item, str(output), laz, formats),
                              lambda p: p | "Files" >> beam.Create(files) | AssembleFiles(str(output), laz, formats),
                              small or threads)
            log_timing("jobs", str(output), laps)
            stop_on_noted_faults(output)  # the parts stay for a resumed run to assemble
            # without Parquet tables run.json counts what the ranges' marks say, read before the parts go
            counted = counts_from_marks(output, tasks) if "parquet" not in formats else {}
        for path in paths:  # their parts are in the assembled files now; other inputs' (fwl watch) stay
            remove_input_outputs(output, names.stem(names.name(path)), (PARTS,))
    finally:
        if early is not None:  # stopped before its ranges: it gets none
            early.abandon(wait=not INTERRUPTED.is_set())
        remove_partial_files(output)
    _write_lost_plans(output, plans)
    # the calibration each input's ranges used, kept in the manifest for a run.json written later
    return JobsDone(len(tasks), len(reused), beam_metrics(result, files_rejected),
                    {path: {**planned_of(plan), **ranges_from.get(path, {}), "calibration": calibration,
                            **({"ranges_counted": counted[plan.source.name]}
                               if plan.source is not None and plan.source.name in counted else {})}
                     for path, plan in plans.items()}, calibration, total)


def stop_on_noted_faults(output: Path, unfinished: int = 0, ranges: int = 0) -> None:
    """RunStopped when the workers noted faults of the machine, or `unfinished` ranges of `ranges` ended without
    their mark; the notes go (those in the temporary folder, outside the output, with them)."""
    faults = noted_faults(output)
    if not faults and not unfinished:
        return
    clear_faults(output)
    raise RunStopped(faults or [output_fault(output, unfinished)], output, ranges - unfinished if ranges else None,
                     ranges or None)


def crs_line(plans: dict[str, FilePlan]) -> str | None:
    """One line for the terminal when a CRS was assigned (--crs) or is unknown (none, or only a unit) for some
    inputs; None when every input names its own."""
    sources = [p.source for p in plans.values() if p.source is not None]
    given = [s for s in sources if s.crs_source == GIVEN]
    if given:
        return f"CRS {crs_name(given[0].crs_wkt)} assigned by --crs to {len(given)} input(s), whatever they say"
    unnamed = [s for s in sources if not s.crs_named and s.crs_wkt]
    unknown = [s for s in sources if not s.crs_wkt]
    if not (unnamed or unknown):
        return None
    said = []
    if unnamed:
        said.append(f"{_names(unnamed)} name(s) no CRS, only its unit: written as {crs_name(unnamed[0].crs_wkt)}")
    if unknown:
        said.append(f"{_names(unknown)} name(s) no CRS: written without one")
    return "; ".join(said) + "; give --crs (an EPSG code, WKT or PROJJSON) to name it"


def _names(sources: list, shown: int = 3) -> str:
    more = f" and {len(sources) - shown} more" if len(sources) > shown else ""
    return ", ".join(s.name for s in sources[:shown]) + more


def _ranges_from(plans: dict[str, FilePlan], radiometry: RadiometryConfig) -> tuple[dict[str, dict], list[str]]:
    """Each planned input's radiometry (where its ranges come from, its beam divergence), for run.json, and why
    those without a range have none (their radiometric columns are null)."""
    found, no_range = {}, []
    for path, plan in plans.items():
        s = plan.source
        if s is None:
            continue
        file = file_radiometry(s.path, s.adjusted_standard_gps_time, radiometry)
        if not file.range_source:
            no_range.append(file.why_no_range)
            LOG.info("no radiometry: %s", file.why_no_range)
        found[path] = {"radiometry": file.to_dict()}
    return found, no_range


def _warn_unmeasured(plans: dict[str, FilePlan]) -> None:
    """On the terminal: the files whose system pulse width was not measured but estimated or defaulted (the
    workers that planned them said so in their own logs only)."""
    for plan in plans.values():
        s = plan.source
        if s is not None and s.pulse.fwhm_source.startswith(("estimated", "default")):
            LOG.warning("%s: system pulse FWHM %.0f ps %s (no single-return pulse measured it; set "
                        "--system-pulse-fwhm-ps to give it)", s.name, s.pulse.fwhm_ps, s.pulse.fwhm_source)
        noise = (s.metric_settings or {}).get("noise", "") if s is not None else ""
        if noise.startswith("estimated"):  # GEDI without L1B's noise fields (fwcore.io.gedi.NOISE_ESTIMATED)
            LOG.warning("%s: GEDI noise %s", s.name, noise)


def _write_lost_plans(output: Path, plans: dict[str, FilePlan]) -> None:
    """rejected/<stem>.parquet for a file whose plan was lost (the plan job writes it for a file it rejects)."""
    for plan in plans.values():
        r = plan.rejection
        if r is not None and not file_rejected(output, r.stem).exists():
            write_file_rejection(output, r)


