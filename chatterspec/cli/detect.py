"""``chatterspec detect NAME``: spectral fault detection on one catalogue scenario."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Iterator
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from ..detection.alarms.calibration import MonitorSettings
    from ..detection.detect import DetectionReport
    from ..detection.identification import IdentificationSetup, IdentificationStream
    from ..detection.pipeline import ChatteringRecord
    from ..detection.thresholds import Threshold
    from ..plants.scenarios import Scenario
    from ..plants.simulate import Simulation
    from ..studies.calibration.result import Calibration
    from ._options import AlarmChoice

from ..errors import ParameterError
from ._options import (
    add,
    add_alarm_args,
    add_detector_args,
    add_execution_args,
    add_identification_args,
    add_live_args,
    add_report_args,
    add_tolerance_args,
    alarm_choice,
    command,
    load_scenario,
    setup_or_reason,
    with_tolerance_args,
)
from ._report import (
    Outputs,
    check_record_path,
    identification_stream,
    interval_docs,
    print_identification,
    print_json,
    print_tolerance,
    record_doc,
    stderr_note,
    tolerance_doc,
)


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``chatterspec detect`` and its options to the subcommand parsers ``sub``."""
    p = command(
        sub,
        "detect",
        run,
        help="detect a fault in a catalogue scenario from its chattering spectrum",
        description="Simulate NAME, run the auxiliary SVSF, compare the chattering periodogram with "
        "chi-squared thresholds and, for multi-segment scenarios, localize the fault with the STFT.",
    )
    p.add_argument(
        "name",
        metavar="NAME",
        help="scenario name (see 'chatterspec scenarios'), or a model file MODEL.toml: its healthy plant "
        "under its [simulation] table (a nonlinear model needs --calibration)",
    )
    add_detector_args(p)
    add_live_args(p)
    add(
        p,
        "--calibration",
        help="use the empirical family-wise threshold of a calibration file written by "
        "'chatterspec calibrate --out FILE' (refused if it was made for another model or length)",
    )
    add_alarm_args(p, what="the --record / --live monitor")
    add_execution_args(p)
    add_identification_args(p)
    add_tolerance_args(p)
    add_report_args(p)
    # None = not given (the defaults of add_detector_args are filled in by run): a calibration fixes
    # the threshold, so an explicit --alpha / --threshold / --correction next to it is refused
    p.set_defaults(alpha=None, threshold=None, correction=None)


#: Defaults of the detector options when no calibration file is given.
DETECTOR_DEFAULTS = {"alpha": 1e-3, "threshold": "exact", "correction": "bonferroni"}


def refuse_with_calibration(args: argparse.Namespace, names: tuple[str, ...]) -> None:
    """Refuse options that a ``--calibration`` file would override (they were silently ignored)."""
    given = [f"--{n.replace('_', '-')}" for n in names if getattr(args, n, None) is not None]
    if getattr(args, "calibration", None) is not None and given:
        raise ParameterError(
            f"{' and '.join(given)} cannot be used with --calibration: the calibration file fixes the "
            "threshold and its alpha (drop the option, or drop --calibration)"
        )


def run(args: argparse.Namespace) -> int:
    """Run ``chatterspec detect`` with the parsed ``args``; returns the exit status."""
    check_record_path(args.record)  # before the (slow) imports: a bad path fails at once
    refuse_with_calibration(args, tuple(DETECTOR_DEFAULTS))
    for key, value in DETECTOR_DEFAULTS.items():
        if getattr(args, key) is None:
            setattr(args, key, value)
    sc = load_scenario(args.name)  # an unknown name fails here, before the heavy imports
    if args.tolerance:
        import dataclasses

        sc = dataclasses.replace(sc, nominal=with_tolerance_args(sc.nominal, args))
    band = args.band
    choice = alarm_choice(args, default_rule=_file_rule(args))  # bad options stop here, before simulating
    from ..detection.detect import detect_chunks

    threshold = args.threshold
    extra: dict = {}
    if args.calibration:
        from ..studies.calibration.result import load_calibration
        from ..studies.calibration.support import require_support

        n_samples = round(sc.duration / sc.nominal.dt)  # chattering samples of one record
        cal = load_calibration(args.calibration, sc.nominal, n_samples)
        require_support(cal, "detect", args.calibration)  # enough runs for its alpha, or refused
        threshold = cal.threshold("family-wise")
        if not sc.is_linear:  # nonlinear: STFT intervals from the calibrated per-frame threshold
            extra["frame_threshold"] = cal.threshold("frame-family-wise")
    first: list = []
    progress = False if args.no_progress or args.runs < PROGRESS_MIN_RUNS else None
    setup, why_not = setup_or_reason(sc.nominal, args)
    pmap = getattr(sc.nominal, "parameter_map", None)
    if setup is None and pmap is not None and pmap.has_tolerances:
        raise ParameterError(
            f"the tolerances are decided on the identified parameters, and there are none: {why_not}"
        )
    ident = None
    parallel = args.workers > 1 or args.scheduler is not None
    if parallel:  # the same numbers from worker processes / Dask
        from ..detection.detect import detect_scenario

        ident = None if setup is None else identification_stream(setup, args)
        report = detect_scenario(
            sc,
            args.runs,
            args.seed,
            args.alpha,
            threshold,
            args.correction,
            band=band,
            workers=args.workers,
            scheduler=args.scheduler,
            progress=progress,
            identification=ident,
            **extra,
        )
        if args.record or args.live or setup is not None:
            from ..plants.simulate import simulate

            first.append(simulate(sc, 1, args.seed))
    else:
        chunks = stream_chunks(sc, args.runs, args.seed, first, measurements=setup is not None)
        if setup is not None:  # identification taps the same chunks as they stream past the detector
            ident = identification_stream(setup, args)
            chunks = ident.tap(chunks, background=True)
        report = detect_chunks(
            with_progress(chunks, args.runs, f"detect {sc.name}", progress),
            args.alpha,
            threshold,
            args.correction,
            band=band,
            **extra,
        )
    sim = first[0] if first else None  # run 0, simulated once: detection and recording
    doc = report.to_dict()
    doc["seed"] = args.seed
    doc["fault_intervals_true"] = [list(iv) for iv in sc.fault_intervals]
    add_identification(doc, report, setup, why_not, ident, sim, sc, args)
    if args.record or args.live:
        from ..online.monitor import MonitorSettings
        from ..viewer.recordings import record_detection

        settings = MonitorSettings(alpha=args.alpha, correction=args.correction, band=band)
        if args.calibration and not sc.is_linear:  # nonlinear: the calibrated per-frame threshold
            settings = MonitorSettings(threshold=cal.threshold("frame-family-wise"), band=band)
        threshold = None  # the per-frame threshold: computed once, for the alarm calibration and the monitor
        if sc.is_linear or settings.threshold is not None:
            from ..detection.thresholds import monitor_threshold

            threshold = monitor_threshold(sc.nominal, settings)
        before = settings
        settings = _alarm_settings(args, choice, sc, settings, cal if args.calibration else None, threshold)
        if not settings.same_frame_threshold(before):  # the verdict drawn at the rule's own level
            threshold = None
        doc["alarm"] = None if settings.budget is None else settings.budget.to_dict()
        outputs = Outputs()
        assert sim is not None  # (simulated above for --record / --live)
        summary = outputs.write(
            "--record", args.record, record_detection, sim, settings, path=args.record, live=args.live,
            threshold=threshold, identification=setup, confidence=args.confidence,
            identification_intervals=doc.get("identification_intervals"),
        )  # fmt: skip
        if summary is not None:
            doc["recording"] = summary.to_dict()
            for note in summary.notes:
                print(note, file=sys.stderr)
    if args.json:
        print_json(doc)
    else:
        print_report(doc)
        print_identification(doc)
        print_tolerance(doc)
    if args.record or args.live:
        outputs.finish()  # a failed recording: the result above is printed first
    return 0


def _file_rule(args: argparse.Namespace) -> str | None:
    """The rule of ``--calibration``'s alarm calibration (the default of ``--rule``), if any."""
    if not args.calibration:
        return None
    from ..studies.calibration.result import load_calibration

    alarm = load_calibration(args.calibration).alarm
    return None if alarm is None else alarm.rule.name


def _alarm_settings(
    args: argparse.Namespace,
    choice: AlarmChoice,
    sc: Scenario,
    settings: MonitorSettings,
    cal: Calibration | None,
    threshold: Threshold | None,
) -> MonitorSettings:
    """The recording monitor's alarm rule: the calibration file's, or set here for the budget (linear,
    calibrated on the monitor's per-frame ``threshold`` for ``settings``); a nonlinear scenario whose
    file holds no alarm calibration keeps the per-frame rule."""
    from ..studies.alarm_budget import alarm_settings
    from ._options import check_file_alarm

    file_alarm = getattr(cal, "alarm", None)
    if file_alarm is not None:
        rc = check_file_alarm(choice, file_alarm, args.calibration)
        return alarm_settings(sc.nominal, settings, calibration=rc)
    if not sc.is_linear:
        print(
            "chatterspec detect: note: the recording's monitor uses the per-frame rule (calibrate "
            f"{args.name}'s healthy scenario with --rule for a false-alarm budget)",
            file=sys.stderr,
        )
        return settings
    c = choice  # AlarmChoice
    return alarm_settings(
        sc.nominal,
        settings,
        c.rule,
        c.budget,
        hours=c.hours,
        note=stderr_note("detect"),
        threshold=threshold,
        **c.parameters,
    )


#: Below this many realizations ``detect`` shows no progress bar (a few seconds at most).
PROGRESS_MIN_RUNS = 1024


def with_progress(
    chunks: Iterator[ChatteringRecord], runs: int, label: str, enabled: bool | None = None
) -> Iterator[ChatteringRecord]:
    """Pass ``chunks`` through, advancing a progress bar on stderr (only on a terminal by default)."""
    from ..progress import Progress

    with Progress(runs, label, enabled=enabled) as bar:
        for rec in chunks:
            yield rec
            bar.update(rec.values.shape[0])


def add_identification(
    doc: dict,
    report: DetectionReport,
    setup: IdentificationSetup | None,
    why_not: str | None,
    ident: IdentificationStream | None,
    sim: Simulation | None,
    sc: Scenario,
    args: argparse.Namespace,
) -> None:
    """``doc["identification"]`` (whole record) and ``doc["identification_intervals"]`` (run 0's
    STFT intervals)."""
    if setup is None:
        doc["identification"] = {"reason": why_not}
        return
    assert ident is not None  # (made with the setup)
    doc["identification"] = record_doc(ident, args.runs, setup, sc)
    tol = tolerance_doc(ident, args.runs, args)
    if tol is not None:
        doc["tolerance"] = tol
    frames = getattr(report, "frames", None)
    if sim is not None and frames is not None and frames.intervals.get("any"):
        hop = frames.spectrogram.config.hop_s
        doc["identification_intervals"] = interval_docs(
            setup, sim.z[:1], sim.u, frames.intervals["any"], sc.duration, hop, args, sc
        )


def stream_chunks(
    sc: Scenario, runs: int, seed: int, first: list[Simulation], *, measurements: bool = False
) -> Iterator[ChatteringRecord]:
    """Chattering records of ``runs`` realizations in chunks; appends run 0's Simulation to ``first``.

    Peak memory is one chunk (``DETECT_CHUNK_RUNS`` realizations), whatever ``runs``. Where the
    fused simulation + auxiliary-SVSF kernel applies (``iter_chattering``'s fast path, the same
    numbers), run 0 is simulated once more on its own for the recording (realization r's
    numbers do not depend on the chunking). With ``measurements`` the records keep z and u
    (fault identification; on the fused path in one reused buffer).
    """
    from ..detection.detect import DETECT_CHUNK_RUNS
    from ..detection.pipeline import can_fuse, chattering_record, iter_chattering
    from ..plants.simulate import iter_simulations, simulate

    if can_fuse(sc):
        first.append(simulate(sc, 1, seed))
        # identification consumes each chunk's z before the next: one buffer serves every chunk
        yield from iter_chattering(
            sc,
            runs,
            seed,
            chunk_runs=min(runs, DETECT_CHUNK_RUNS),
            measurements=measurements,
            reuse_measurements=measurements,
        )
        return
    for sim in iter_simulations(sc, runs, seed, chunk_runs=min(runs, DETECT_CHUNK_RUNS)):
        if not first:
            first.append(sim.take(slice(0, 1)))
        yield chattering_record(sc.nominal, sim.z, sim.u, scenario=sc, first_run=sim.first_run)


def print_report(doc: dict) -> None:
    """Print the detection report ``doc`` (the JSON document) as a table."""
    from ..detection.detect import detection_table

    print(detection_table(doc))
    if "recording" in doc and doc["recording"]["recording"]:
        rrd = doc["recording"]["recording"]
        print(f"recording: {rrd}  (open with: chatterspec replay {rrd})")
