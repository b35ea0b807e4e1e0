"""``chatterspec diagnose NAME [--false-alarms-per-hour X] [--rule R] [--methods ...] [--runs N] ...``:
the diagnosis routes compared at one false-alarm budget, on the same realizations.

Routes (:mod:`chatterspec.studies.budget_diagnosis`): ``chattering`` (``-log p`` of the STFT frames of the
auxiliary SVSF's chattering), ``smm`` and ``imm`` (log posterior odds of the fault modes), ``innovation``
(the Kalman filter's / EKF's normalized innovation squared, Mehra and Peschon 1971). Every route's
score goes through the same alarm rule (``--rule``, default ``cusum``), whose threshold is calibrated
per route on healthy runs of the scenario's healthy version (seeds disjoint from the diagnosed runs)
to ``--false-alarms-per-hour`` alarm starts per hour (:mod:`chatterspec.studies.budget_diagnosis`).

Per route: the false alarms realized on the diagnosed runs' healthy time (before the first onset, after
``--warmup``) per hour with their two-sided Poisson (Garwood) interval, the detection delay per onset
(median, 90th percentile), missed onsets, isolation, the cost (realization-samples per second), and
``--plot FILE.png``: the detection delay against the false alarms per hour with the thresholds
swept on the same realizations. ``--per-record`` gives the former table instead (each route with its
own rule: argmax of the modes, per-frame chattering at ``--alpha``), which cannot rank the routes.

``--onset S`` moves the fault of a scenario faulty from ``t = 0`` (``eha-leak-minor``) to ``S`` seconds,
so that it has healthy time. ``--workers`` / ``--scheduler`` / ``--chunk-runs`` as for the other Monte
Carlo commands: the numbers do not depend on them.
"""

from __future__ import annotations

import argparse
import math
import time
from typing import TYPE_CHECKING, Any, cast

from ..errors import ParameterError
from ._options import (
    add,
    add_execution_args,
    add_identification_args,
    add_name,
    add_report_args,
    add_runs_args,
    add_tolerance_args,
    command,
    execution,
    positive_int_arg,
    setup_or_reason,
    with_tolerance_args,
)
from ._report import Outputs, check_figure_path, check_record_path, print_diagnosis, print_json, report

if TYPE_CHECKING:  # pragma: no cover
    from collections.abc import Iterator

    from ..detection.thresholds import Threshold
    from ..plants.scenarios import Scenario
    from ..plants.simulate import Simulation
    from ..studies.budget_diagnosis import BudgetSettings, Route


#: Healthy runs of the budget's calibration streams by default: on eha4-leak-timeline (9 s records) 500 runs
#: (1.2 h) are too few for the alarm layer to extrapolate the chattering and innovation routes' CUSUM to one
#: false alarm per hour (the fitted counts span less than a factor e); 1000 (2.3-2.5 h) are enough.
DEFAULT_CALIBRATION_RUNS = 1000

#: The routes of :data:`chatterspec.studies.budget_diagnosis.ALL_METHODS` and the start-up default
#: :data:`chatterspec.studies.budget_diagnosis.DEFAULT_WARMUP_S` (s), listed here so that building the parser
#: (``chatterspec --help``) does not import numpy; a test keeps them equal.
METHOD_NAMES: tuple[str, ...] = ("chattering", "smm", "imm", "innovation", "parameters")
WARMUP_S = 0.1
#: Rule parameters every route sets itself
#: (:data:`chatterspec.studies.budget_diagnosis.ROUTE_RULE_PARAMETERS`): their options are not offered.
ROUTE_SET: tuple[str, ...] = ("drift",)


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``chatterspec diagnose`` and its options to the subcommand parsers ``sub``."""
    from ..detection.alarms.rules import rule_names
    from ._options import add_rule_parameter_args

    p = command(
        sub,
        "diagnose",
        run,
        help="fault diagnosis routes (chattering, SMM-SVSF, IMM, innovations) at one false-alarm budget",
        description="Runs each route on the same seeded realizations through one alarm rule whose "
        "threshold is calibrated per route on healthy runs to the same false alarms per hour, and reports "
        "per route the realized false-alarm rate (Poisson interval), the detection delay per fault onset "
        "(median, 90th percentile), missed onsets, isolation and the cost.",
    )
    add_name(p, "scenario (e.g. eha4-leak-timeline, eha-leak-minor --onset 2)")
    p.add_argument(
        "--methods",
        default=None,
        help=f"comma-separated subset of {','.join(METHOD_NAMES)} (default: every one the scenario supports)",
    )
    add_runs_args(p, 10, runs_help="realizations (default 10)")
    add(
        p,
        "--false-alarms-per-hour",
        default="1",
        help="false-alarm budget of every route: alarm starts per hour of healthy time (default 1)",
    )
    add(p, "--rule", choices=rule_names(), help="alarm rule of every route (default cusum)")
    # each route sets its own CUSUM drift (routes.Route.rule_parameters)
    add_rule_parameter_args(p, step="step", steps="steps (frames or samples)", skip=ROUTE_SET)
    p.add_argument(
        "--warmup",
        type=float,
        default=WARMUP_S,
        metavar="S",
        help=f"seconds of start-up not fed to the rules (default {WARMUP_S:g})",
    )
    p.add_argument(
        "--nis-inflation",
        type=float,
        default=None,
        metavar="L",
        help="innovation route: covariance inflation L > 1 of its CUSUM likelihood ratio (default 1.5)",
    )
    p.add_argument(
        "--onset",
        type=float,
        default=None,
        metavar="S",
        help="a scenario faulty from t = 0: start its fault at S seconds instead (healthy before)",
    )
    add(
        p,
        "--calibration",
        default=None,
        help="chattering on a nonlinear model: saved calibration of the nominal model (its expected "
        "spectrum is the frame score's healthy law; default: calibrate on healthy runs now)",
    )
    p.add_argument(
        "--calibration-runs",
        type=positive_int_arg,
        default=None,
        help=f"healthy runs of the in-call calibrations (default {DEFAULT_CALIBRATION_RUNS}; "
        "--per-record: 500, not with --calibration)",
    )
    add(
        p,
        "--alpha",
        default=None,
        help="chattering: per-frame level of the in-call calibration, the --per-record threshold and the "
        "recording (default 0.001; not with --calibration)",
    )
    add_execution_args(
        p,
        chunk_runs_help="realizations simulated and diagnosed together (memory grows with it, not with "
        "--runs; the results do not depend on it)",
    )
    add(p, "--plot", help="save the delay-vs-false-alarms figure")
    p.add_argument(
        "--per-record", action="store_true", help="each route with its own rule (the former table)"
    )
    add_identification_args(p)
    add_tolerance_args(p)
    add_report_args(p, json_help="print one JSON document")
    add(p, "--record", default=None, help="write realization 0 to a Rerun file")


def _methods(text: str | None, sc: Scenario, per_record: bool) -> tuple[str, ...]:
    from ..studies.budget_diagnosis import ALL_METHODS, supported_methods, unsupported_reason

    allowed = tuple(m for m in ALL_METHODS if not (per_record and m == "innovation"))
    supported = tuple(m for m in supported_methods(sc) if m in allowed)
    if text is None:
        if not supported:
            raise ParameterError(
                f"scenario {sc.name!r} supports no diagnosis method here; try eha4-leak-timeline"
            )
        return supported
    names = tuple(s.strip() for s in text.split(",") if s.strip())
    if not names:
        raise ParameterError(f"--methods takes a comma-separated subset of {','.join(ALL_METHODS)}; got none")
    for name in names:
        if name not in ALL_METHODS:
            raise ParameterError(
                f"--methods takes a comma-separated subset of {','.join(ALL_METHODS)}; got {name!r}"
            )
        if name not in allowed:
            raise ParameterError("--methods innovation runs at a false-alarm budget only (drop --per-record)")
        why = unsupported_reason(sc, name)
        if why is not None:
            raise ParameterError(
                f"scenario {sc.name!r} does not support --methods {name} (it needs {why}); "
                f"supported here: {','.join(supported) or 'none'}"
            )
    return tuple(dict.fromkeys(names))


def _scenario(args: argparse.Namespace) -> Scenario:
    from ..plants.scenarios import scenario
    from ..studies.budget_diagnosis import onsets_of

    sc = scenario(args.name)
    if args.tolerance:
        import dataclasses

        sc = dataclasses.replace(sc, nominal=with_tolerance_args(sc.nominal, args))
    if args.onset is not None:
        from ..studies.diagnosis import with_onset

        sc = with_onset(sc, args.onset)
    if not onsets_of(sc):
        raise ParameterError(
            f"scenario {sc.name!r} has no fault onset to diagnose (it is healthy); for false alarms on "
            "healthy data use `chatterspec far` or `chatterspec monitor`"
        )
    return sc


def _settings(args: argparse.Namespace) -> BudgetSettings:
    from ..studies.budget_diagnosis import BudgetSettings
    from ._options import alarm_choice

    choice = alarm_choice(args)  # the monitor's checks: one line naming the option
    if not (args.warmup >= 0 and args.warmup < float("inf")):
        raise ParameterError(f"--warmup must be a finite number of seconds >= 0; got {args.warmup!r}")
    params = tuple(sorted(choice.parameters.items()))
    return BudgetSettings(choice.budget, choice.rule, params, args.warmup, args.calibration_runs)


def _routes(
    args: argparse.Namespace, sc: Scenario, methods: tuple[str, ...]
) -> tuple[dict[str, Route], Threshold | None, dict[str, Any]]:
    """The route objects, the per-frame threshold of the recording (chattering) and its provenance."""
    from ..detection.alarms.rules import rule_spec
    from ..studies.budget_diagnosis import ChatteringRoute, InnovationRoute, ModeRoute, ParameterRoute
    from ._options import DEFAULT_RULE

    routes: dict[str, Route] = {}
    threshold: Threshold | None = None
    info: dict[str, Any] = {}
    for m in methods:
        if m == "chattering":
            threshold, info = _chattering_law(args, sc)
            routes[m] = ChatteringRoute(sc, threshold)
        elif m == "parameters":
            routes[m] = ParameterRoute(sc)
        elif m == "innovation":
            kw = {} if args.nis_inflation is None else {"inflation": args.nis_inflation}
            routes[m] = InnovationRoute(sc, cap=rule_spec(args.rule or DEFAULT_RULE).accumulates, **kw)
        else:
            routes[m] = ModeRoute(sc, m)
    return routes, threshold, info


def _chattering_law(args: argparse.Namespace, sc: Scenario) -> tuple[Threshold, dict[str, Any]]:
    """The healthy law of the chattering frame score: exact for a linear model, else calibrated."""
    if sc.is_linear:
        if args.calibration is not None:
            raise ParameterError(
                "--calibration: a linear model's frame score uses its exact law, not a calibration file; "
                "drop --calibration (or give --per-record for the per-frame table)"
            )
        from ..detection.spectral import STFTConfig, spectrum_model
        from ..detection.thresholds import frame_threshold

        model, config = spectrum_model(sc.nominal), STFTConfig()
        th = frame_threshold(model, config.freqs_hz(model.dt), config, model.dt, args.alpha)
        return th, {"source": "exact law of the linear model", "alpha": args.alpha}

    return chattering_threshold(args, sc)


def run(args: argparse.Namespace) -> int:
    """Run ``chatterspec diagnose`` with the parsed ``args``; returns the exit status."""
    from .detect import refuse_with_calibration

    check_record_path(args.record)
    # a calibration file fixes the chattering threshold and its alpha; at a budget, --calibration-runs
    # also sets the healthy streams of every route, so it stays allowed there
    refuse_with_calibration(args, ("alpha", "calibration_runs") if args.per_record else ("alpha",))
    args.alpha = 1e-3 if args.alpha is None else args.alpha
    if (
        args.calibration_runs is None
    ):  # at a budget, 500 runs (1.2 h of 9 s records) cannot calibrate every route
        args.calibration_runs = 500 if args.per_record else DEFAULT_CALIBRATION_RUNS
    check_figure_path(args.plot)
    sc = _scenario(args)
    methods = _methods(args.methods, sc, args.per_record)
    if args.per_record:
        if args.plot is not None:
            raise ParameterError("--plot draws the comparison at a budget; drop --per-record")
        return run_per_record(args, sc, methods)
    settings = _settings(args)
    from ..studies.budget_diagnosis import diagnose_at_budget

    t0 = time.perf_counter()
    routes, threshold, law_info = _routes(args, sc, methods)
    results = diagnose_at_budget(
        sc,
        routes,
        args.runs,
        args.seed,
        settings,
        **execution(args),
    )
    ident_doc = identification_doc(args, sc)
    wall = time.perf_counter() - t0
    outputs = Outputs()
    figure = recording = None
    if args.plot is not None:
        from ..figures.plot_diagnosis import delay_far_figure
        from ..figures.plot_studies import save

        at = f"{settings.rule} rule at {settings.budget_per_hour:g} false alarm(s)/h"
        title = f"{sc.name}: {args.runs} runs, {at}"
        figure = outputs.write("--plot", args.plot, save, delay_far_figure(results, title), args.plot)
    if args.record is not None:
        from ..viewer.recordings import record_budget_diagnosis

        recording = outputs.write(
            "--record",
            args.record,
            record_budget_diagnosis,
            args.record,
            sc,
            args.seed,
            routes,
            results,
            threshold,
        )
    doc = {
        "scenario": sc.name,
        "runs": args.runs,
        "seed": args.seed,
        "budget_per_hour": settings.budget_per_hour,
        "rule": settings.rule,
        "warmup_s": settings.warmup_s,
        "chattering_law": law_info or None,
        "wall_s": wall,
        "methods": [r.describe() for r in results],
        "figure": None if figure is None else str(figure),
        "identification": ident_doc,
        "recording": None if recording is None else str(recording),
    }

    def text() -> None:
        _print_budget_table(sc, args, settings, results, wall)
        print_diagnosis(ident_doc)
        if figure is not None:
            print(f"figure: {figure}")
        if recording is not None:
            print(
                f"recording: {recording} (open with `chatterspec replay {recording}` or `rerun {recording}`)"
            )

    return report(args, doc, outputs, text)


def _print_budget_table(
    sc: Scenario, args: argparse.Namespace, settings: BudgetSettings, results: list, wall: float
) -> None:
    from ..figures.plot_diagnosis import budget_rows

    print(
        f"diagnosis on {sc.name}: {args.runs} runs, seed {args.seed}; {settings.rule} rule, every route "
        f"calibrated to {settings.budget_per_hour:g} false alarm(s) per hour on healthy streams "
        f"({settings.calibration_runs} runs; how, per route, below); warm-up {settings.warmup_s:g} s; "
        f"{wall:.1f} s"
    )
    header, rows = budget_rows(results)
    widths = [max(len(str(r[i])) for r in [header, *rows]) for i in range(len(header))]
    for r in [header, *rows]:
        print("  ".join(str(c).ljust(w) for c, w in zip(r, widths, strict=True)).rstrip())
    for r in results:
        c = r.calibration
        how = c.get("describe") or c.get("reason", "")
        print(f"{r.method}: {how}" + (f"; {c['never_alarms']}" if "never_alarms" in c else ""))


def identification_doc(args: argparse.Namespace, sc: Scenario) -> dict:
    """Fault identification per fault segment on the diagnosed realizations (seed ``--seed``, the
    routes' runs), at test level ``--alpha``; ``{"reason": ...}`` where the model gives none."""
    setup, why_not = setup_or_reason(sc.nominal, args)
    if setup is None:
        return {"reason": why_not}
    from ..plants.simulate import iter_simulations
    from ..studies.diagnosis import IdentificationTally

    tally = IdentificationTally(sc, setup, alpha=args.alpha, confidence=args.confidence)
    chunk = min(args.chunk_runs or 64, args.runs)
    for sim in iter_simulations(sc, args.runs, args.seed, chunk_runs=chunk):
        tally.add(sim)
    return {
        "alpha": args.alpha,
        "confidence": args.confidence,
        "segments": [r.to_dict() for r in tally.result()],
    }


# ----------------------------------------------------------------------------------------------------
# ``chatterspec diagnose --per-record``: each route with its own rule, as the papers report them.
#
# * ``smm``, ``imm``: alarm while the most probable mode is a fault mode (the argmax rule);
# * ``chattering``: the per-frame, family-wise threshold at ``--alpha`` (calibrated on healthy runs
#   of the scenario's healthy version, or read from ``--calibration FILE``).
#
# False alarms are family-wise per run (99 % Clopper-Pearson), on the healthy segments. These rules do
# not alarm equally often, so the delays of this table cannot rank the routes; ``diagnose`` without
# ``--per-record`` compares them at one false-alarm budget (above).
#
# The runs are simulated and diagnosed in chunks of ``--chunk-runs`` (default 64): only per-run figures
# are kept, so the memory does not grow with ``--runs``, and the output does not depend on the chunking;
# with ``--workers`` / ``--scheduler`` the chunks run on worker processes
# (:func:`~chatterspec.studies.diagnosis.diagnose_parallel`), with the same figures.


def chattering_threshold(args: argparse.Namespace, sc: Scenario) -> tuple[Threshold, dict[str, Any]]:
    """The chattering route's per-frame threshold at ``--alpha`` and its provenance.

    From ``--calibration FILE`` (refused without enough runs for the per-frame threshold), or
    calibrated now on ``--calibration-runs`` healthy runs of the scenario's healthy version
    (:func:`~chatterspec.studies.diagnosis.calibrate_for_diagnosis`, on ``--workers`` /
    ``--scheduler``). Its expected spectrum is also the healthy law of the frame score of a nonlinear
    model at a budget.
    """
    from ..detection.spectral import STFTConfig

    config = STFTConfig()
    if args.calibration is not None:
        from ..studies.calibration.result import load_calibration
        from ..studies.calibration.support import require_support

        cal = load_calibration(args.calibration, sc.nominal, config=config)
        require_support(cal, "monitor", args.calibration)  # the per-frame threshold needs enough runs
        info = {"source": str(args.calibration), "runs": cal.runs, "alpha": cal.alpha, "seconds": 0.0}
    else:
        from ..studies.diagnosis import CALIBRATION_SALT, calibrate_for_diagnosis

        t0 = time.perf_counter()
        cal = calibrate_for_diagnosis(
            sc,
            args.seed,
            runs=args.calibration_runs,
            alpha=args.alpha,
            progress=False if args.no_progress else None,
            workers=args.workers,
            scheduler=args.scheduler,
        )
        info = {
            "source": "calibrated now on healthy runs",
            "runs": cal.runs,
            "pilot_runs": cal.normalization_info.get("pilot_runs", 0),
            "alpha": cal.alpha,
            "seed": f"SeedSequence([{args.seed}, {CALIBRATION_SALT:#x}])",
            "seconds": time.perf_counter() - t0,
        }
    q = cal.frame_family_wise
    # per channel: the per-frame (1 - alpha)-quantile of max S / E_hat and its interval (inf: unbounded)
    info["frame_quantile"] = [
        [x if math.isfinite(x) else None for x in (v.value, v.ci_low, v.ci_high)] for v in q
    ]
    return cal.threshold("frame-family-wise"), info


#: Realizations per chunk by default: the mode filters' outputs (runs, T, r) of a 9 s EHA record and the
#: chattering spectrogram of a chunk stay well under 100 MB (the peak RSS does not grow with --runs).
DEFAULT_CHUNK_RUNS = 64


def run_per_record(args: argparse.Namespace, sc: Scenario, methods: tuple[str, ...]) -> int:
    """``diagnose --per-record``: each route with its own rule (argmax; per-frame at ``--alpha``)."""
    from ..plants.simulate import iter_simulations

    threshold, info = chattering_threshold(args, sc) if "chattering" in methods else (None, {})
    from ..studies.diagnosis import ChatteringTally, ModeTally

    # the runs go through in chunks (realization r's numbers do not depend on the chunking); only per-run
    # figures are kept, and realization 0 for --record
    outputs: dict = {}
    first: Simulation | None = None
    sim_s: float | None = None  # seconds spent simulating (None: on workers, inside their chunks)
    chunk = args.chunk_runs or DEFAULT_CHUNK_RUNS
    # fault identification beside the routes: per segment, on the same realizations (test level --alpha)
    setup, why_not = setup_or_reason(sc.nominal, args)
    ident = None
    parallel = args.workers > 1 or args.scheduler is not None
    if setup is not None and not parallel:
        from ..studies.diagnosis import IdentificationTally

        ident = IdentificationTally(sc, setup, alpha=args.alpha, confidence=args.confidence)
    if parallel:  # simulation and filters on workers: same figures
        from ..plants.simulate import simulate
        from ..studies.diagnosis import diagnose_parallel

        tallies, outputs = diagnose_parallel(
            sc,
            methods,
            threshold,
            args.runs,
            args.seed,
            workers=args.workers,
            scheduler=args.scheduler,
            chunk_runs=chunk,
            progress=False if args.no_progress else None,
            keep=args.record is not None,
            identification=None if setup is None else (setup, args.alpha, args.confidence),
        )
        if setup is not None:
            from ..studies.diagnosis import IdentificationTally

            last = tallies.pop()  # the identification tally comes last
            assert isinstance(last, IdentificationTally)
            ident = last
        if args.record is not None:
            first = simulate(sc, 1, args.seed)
    else:
        chunks = iter_simulations(sc, args.runs, args.seed, chunk_runs=min(chunk, args.runs))
        tallies = [
            ChatteringTally(sc, cast("Threshold", threshold)) if m == "chattering" else ModeTally(sc, m)
            for m in methods
        ]  # (threshold: given with the chattering route)
        first, sim_s = _serial(args, sc, [*tallies, *([ident] if ident is not None else [])], chunks, outputs)
    results = [
        t.result(info) if isinstance(t, ChatteringTally) else cast(ModeTally, t).result() for t in tallies
    ]
    ident_doc = (
        {"reason": why_not}
        if ident is None
        else {
            "alpha": args.alpha,
            "confidence": args.confidence,
            "segments": [r.to_dict() for r in ident.result()],
        }
    )
    recording, written = None, Outputs()  # a recording that fails: the result first, then exit 2
    if args.record is not None:
        from ..viewer.recordings import record_diagnosis

        assert first is not None  # (realization 0, kept for --record)
        recording = written.write(
            "--record", args.record, record_diagnosis, args.record, first, threshold, outputs
        )
    if args.json:
        print_json(
            {
                "scenario": sc.name,
                "runs": args.runs,
                "seed": args.seed,
                "simulation_s": sim_s,
                "methods": [r.describe() for r in results],
                "identification": ident_doc,
                "recording": None if recording is None else str(recording),
            }
        )
        written.finish()
        return 0
    _print_table(sc, args, results)
    print_diagnosis(ident_doc)
    if recording is not None:
        print(f"recording: {recording} (open with `chatterspec replay {recording}` or `rerun {recording}`)")
    written.finish()
    return 0


def _serial(
    args: argparse.Namespace, sc: Scenario, tallies: list, chunks: Iterator[Simulation], outputs: dict
) -> tuple[Simulation | None, float]:
    """The in-process loop over chunks: realization 0 (for --record, else None) and the simulation time."""
    from ..progress import Progress
    from ..studies.diagnosis import ModeTally

    first, sim_s = None, 0.0
    with Progress(args.runs, "diagnose", enabled=False if args.no_progress else None) as bar:
        while True:
            t0 = time.perf_counter()
            sim = next(chunks, None)
            sim_s += time.perf_counter() - t0
            if sim is None:
                break
            if args.record is not None and first is None:
                first = sim.take(slice(0, 1))
            for tally in tallies:
                if isinstance(tally, ModeTally):
                    tally.add(sim, keep=outputs if args.record else None, keep_runs=1)
                else:
                    tally.add(sim)
            bar.update(sim.runs)
            del sim
    return first, sim_s


def _print_table(sc: Scenario, args: argparse.Namespace, results: list) -> None:
    from ..figures.plot_diagnosis import diagnosis_rows

    print(f"diagnosis on {sc.name}: {args.runs} runs, seed {args.seed} (per record: each route's own rule)")
    header, rows = diagnosis_rows(results)
    widths = [max(len(str(r[i])) for r in [header, *rows]) for i in range(len(header))]
    for r in [header, *rows]:
        print("  ".join(str(c).ljust(w) for c, w in zip(r, widths, strict=True)).rstrip())
    for r in results:
        if r.method == "chattering":
            c = r.calibration
            healthy = (
                f"{r.healthy_frames_per_run} healthy frames per run, flag fraction there "
                f"{r.healthy_alarm_fraction:.4f}"
                if r.healthy_frames_per_run
                else "no healthy frames (faulty from the start: no false-alarm figure)"
            )
            print(
                f"chattering threshold: {c.get('source')} ({c.get('runs')} runs, alpha "
                f"{c.get('alpha'):g} per frame, {c.get('seconds', 0.0):.1f} s); {healthy}; delays are "
                f"frame-end times (hop quantized); runs already in alarm at each onset: "
                f"{list(r.in_alarm_at_onset)}"
            )
        else:
            diag = ", ".join(f"{m} {r.confusion[j, j]:.1f}%" for j, m in enumerate(r.modes))
            print(f"{r.method} confusion diagonal (mean probability of the true mode): {diag}")
