"""``chatterspec diagnose NAME [--false-alarms-per-hour X] [--rule R] [--methods ...] [--runs N] ...``:
the diagnosis routes compared at one false-alarm budget, on the same realizations.

Routes (:mod:`chatterspec.studies.routes`): ``chattering`` (``-log p`` of the STFT frames of the
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
import time
from typing import TYPE_CHECKING, Any

from ..errors import ParameterError
from . import _identify
from ._common import Outputs, check_figure_path, check_record_path, positive_int_arg, report
from ._options import add, add_execution_args, add_name, add_report_args, add_runs_args, command, execution

if TYPE_CHECKING:  # pragma: no cover
    from ..detection.thresholds import Threshold
    from ..plants.scenarios import Scenario
    from ..studies.budget_diagnosis import BudgetSettings
    from ..studies.routes import Route

#: Healthy runs of the budget's calibration streams by default: on eha4-leak-timeline (9 s records) 500 runs
#: (1.2 h) are too few for the alarm layer to extrapolate the chattering and innovation routes' CUSUM to one
#: false alarm per hour (the fitted counts span less than a factor e); 1000 (2.3-2.5 h) are enough.
DEFAULT_CALIBRATION_RUNS = 1000

#: The routes of :data:`chatterspec.studies.routes.ALL_METHODS` and the start-up default
#: :data:`chatterspec.studies.route_sweep.DEFAULT_WARMUP_S` (s), listed here so that building the parser
#: (``chatterspec --help``) does not import numpy; a test keeps them equal.
METHOD_NAMES: tuple[str, ...] = ("chattering", "smm", "imm", "innovation", "parameters")
WARMUP_S = 0.1
#: Rule parameters every route sets itself (:data:`chatterspec.studies.routes.ROUTE_RULE_PARAMETERS`):
#: their options are not offered.
ROUTE_SET: tuple[str, ...] = ("drift",)


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``chatterspec diagnose`` and its options to the subcommand parsers ``sub``."""
    from ..detection.alarms.rules import rule_names
    from ._alarm_args import add_rule_parameter_args

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
    _identify.add_identification_args(p)
    _identify.add_tolerance_args(p)
    add_report_args(p, json_help="print one JSON document")
    add(p, "--record", default=None, help="write realization 0 to a Rerun file")


def _methods(text: str | None, sc: Scenario, per_record: bool) -> tuple[str, ...]:
    from ..studies.routes import ALL_METHODS, supported_methods, unsupported_reason

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
    from ..studies.route_sweep import onsets_of

    sc = scenario(args.name)
    if args.tolerance:
        import dataclasses

        sc = dataclasses.replace(sc, nominal=_identify.with_tolerance_args(sc.nominal, args))
    if args.onset is not None:
        from ..studies.scenario_variants import with_onset

        sc = with_onset(sc, args.onset)
    if not onsets_of(sc):
        raise ParameterError(
            f"scenario {sc.name!r} has no fault onset to diagnose (it is healthy); for false alarms on "
            "healthy data use `chatterspec far` or `chatterspec monitor`"
        )
    return sc


def _settings(args: argparse.Namespace) -> BudgetSettings:
    from ..studies.budget_diagnosis import BudgetSettings
    from ._alarm_args import alarm_choice

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
    from ..studies.routes import ChatteringRoute, InnovationRoute, ModeRoute, ParameterRoute
    from ._alarm_args import DEFAULT_RULE

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
    from ._diagnose_per_record import chattering_threshold

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
        from ._diagnose_per_record import run_per_record

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
        _identify.print_diagnosis(ident_doc)
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
    setup, why_not = _identify.setup_or_reason(sc.nominal, args)
    if setup is None:
        return {"reason": why_not}
    from ..plants.simulate import iter_simulations
    from ..studies.identification_diagnosis import IdentificationTally

    tally = IdentificationTally(sc, setup, alpha=args.alpha, confidence=args.confidence)
    chunk = min(args.chunk_runs or 64, args.runs)
    for sim in iter_simulations(sc, args.runs, args.seed, chunk_runs=chunk):
        tally.add(sim)
    return {
        "alpha": args.alpha,
        "confidence": args.confidence,
        "segments": [r.to_dict() for r in tally.result()],
    }
