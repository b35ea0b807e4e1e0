"""``chatterspec diagnose NAME [--methods chattering,smm,imm] [--runs N] [--seed S] [--chunk-runs K]
[--json] [--record FILE.rrd] [--no-progress]``: fault diagnosis side by side, every method on the same
realizations (``docs/design.md`` §2, the estimator routes).

* ``smm``, ``imm``: mode probabilities (:mod:`chatterspec.studies.mode_diagnosis`);
* ``chattering``: the STFT of the auxiliary sgn-SVSF's chattering against a calibrated per-frame threshold
  (:mod:`chatterspec.studies.chattering_diagnosis`). The threshold is calibrated once per call on healthy
  runs of the scenario's healthy version (other seeds; ``--calibration-runs`` runs plus, for a nonlinear
  model, 200 pilot runs), or read from ``--calibration FILE`` (``chatterspec calibrate ... --save``; it
  must be for the same nominal model and STFT settings; the per-frame threshold does not depend on the
  record length).

The runs are simulated and diagnosed in chunks of ``--chunk-runs`` (default 64): only per-run figures
(delays, alarm flags, counts) are kept, so the memory does not grow with ``--runs``, and the output does
not depend on the chunking (:class:`~chatterspec.studies.chattering_diagnosis.ChatteringTally`,
:class:`~chatterspec.studies.mode_diagnosis.ModeTally`). A progress bar goes to stderr on a terminal
(``--no-progress`` turns it off).

``--record FILE.rrd`` writes realization 0 to Rerun: the chattering spectrogram, frame verdicts and
detection events of the online monitor, and the mode probabilities of smm / imm on the same timeline.
"""

from __future__ import annotations

import argparse
import math
import time

from ..errors import ParameterError
from . import _identify
from ._common import Outputs, add_execution_args, alpha_arg, check_record_path, positive_int_arg, print_json

#: Every method ``--methods`` accepts.
ALL_METHODS = ("chattering", "smm", "imm")


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "diagnose",
        help="fault diagnosis side by side (chattering spectrum, SMM-SVSF, IMM) on the same realizations",
        description="Runs each method on the same seeded realizations and reports false alarms on the "
        "healthy segments (family-wise per run, 99%% Clopper-Pearson), detection delays per fault onset "
        "(median, 90th percentile), isolation (confusion matrix; chattering: flagged channel and peak "
        "frequency per segment) and the cost.",
    )
    p.add_argument("name", metavar="NAME", help="scenario (e.g. eha4-leak-timeline, eha4-imm-analogue)")
    p.add_argument(
        "--methods",
        default=None,
        help="comma-separated subset of chattering,smm,imm (default: every method the scenario supports)",
    )
    p.add_argument("--runs", type=positive_int_arg, default=10, help="realizations (default 10)")
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    p.add_argument(
        "--calibration",
        metavar="FILE",
        default=None,
        help="chattering: saved calibration of the nominal model (default: calibrate on healthy runs now)",
    )
    p.add_argument(
        "--calibration-runs",
        type=positive_int_arg,
        default=None,
        help="chattering: healthy runs of the in-call calibration (default 500; not with --calibration)",
    )
    p.add_argument(
        "--alpha",
        type=alpha_arg,
        default=None,
        help="chattering: per-frame false-alarm probability of the in-call calibration (default 1e-3; not "
        "with --calibration)",
    )
    p.add_argument(
        "--chunk-runs",
        type=positive_int_arg,
        default=None,
        help=f"realizations simulated and diagnosed together (default {DEFAULT_CHUNK_RUNS}; memory grows "
        "with it, not with --runs; the results do not depend on it)",
    )
    add_execution_args(p)
    _identify.add_identification_args(p)
    p.add_argument("--json", action="store_true", help="print one JSON document")
    p.add_argument("--no-progress", action="store_true", help="no progress bar on stderr")
    p.add_argument("--record", metavar="FILE.rrd", default=None, help="write realization 0 to a Rerun file")
    p.set_defaults(func=run)


def _supported(sc: object) -> tuple[str, ...]:
    """The methods the scenario supports, in ALL_METHODS order."""
    out = []
    if getattr(sc.nominal, "full_measurement", False) and not sc.is_healthy:  # type: ignore[attr-defined]
        out.append("chattering")
    fs = sc.filter_settings  # type: ignore[attr-defined]
    if fs is not None and fs.modes:
        if fs.psi is not None:
            out.append("smm")
        if fs.transition_matrix is not None:
            out.append("imm")
    return tuple(out)


def _methods(text: str | None, sc: object) -> tuple[str, ...]:
    supported = _supported(sc)
    if text is None:
        if not supported:
            raise ParameterError(
                f"scenario {sc.name!r} supports no diagnosis method (it needs a fault and a full "  # type: ignore[attr-defined]
                "measurement, or filter_settings modes); try eha4-leak-timeline or eha4-imm-analogue"
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
        if name not in supported:
            why = {
                "chattering": "a faulty scenario whose nominal model measures every state",
                "smm": "filter_settings with modes and psi",
                "imm": "filter_settings with modes and a transition matrix",
            }[name]
            raise ParameterError(
                f"scenario {sc.name!r} does not support --methods {name} (it needs {why}); "  # type: ignore[attr-defined]
                f"supported here: {','.join(supported) or 'none'}"
            )
    return tuple(dict.fromkeys(names))


def _threshold(args: argparse.Namespace, sc: object) -> tuple[object, dict]:
    from ..detection.spectral import STFTConfig

    config = STFTConfig()
    if args.calibration is not None:
        from ..studies.calibration import load_calibration
        from ..studies.calibration_support import require_support

        cal = load_calibration(args.calibration, sc.nominal, config=config)  # type: ignore[attr-defined]
        require_support(cal, "monitor", args.calibration)  # the per-frame threshold needs enough runs
        info = {"source": str(args.calibration), "runs": cal.runs, "alpha": cal.alpha, "seconds": 0.0}
    else:
        from ..studies.chattering_diagnosis import CALIBRATION_SALT, calibrate_for_diagnosis

        t0 = time.perf_counter()
        cal = calibrate_for_diagnosis(
            sc,
            args.seed,
            runs=args.calibration_runs,
            alpha=args.alpha,
            progress=False if args.no_progress else None,
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


def run(args: argparse.Namespace) -> int:
    from ..plants.scenarios import scenario
    from .detect import refuse_with_calibration

    check_record_path(args.record)
    refuse_with_calibration(args, ("alpha", "calibration_runs"))
    args.alpha = 1e-3 if args.alpha is None else args.alpha
    args.calibration_runs = 500 if args.calibration_runs is None else args.calibration_runs
    sc = scenario(args.name)
    methods = _methods(args.methods, sc)
    from ..plants.simulate import Simulation, iter_simulations

    threshold, info = _threshold(args, sc) if "chattering" in methods else (None, {})
    from ..studies.chattering_diagnosis import ChatteringTally
    from ..studies.mode_diagnosis import ModeTally

    # the runs go through in chunks (realization r's numbers do not depend on the chunking); only per-run
    # figures are kept, and realization 0 for --record
    outputs: dict = {}
    first: Simulation | None = None
    sim_s: float | None = None  # seconds spent simulating (None: on workers, inside their chunks)
    chunk = args.chunk_runs or DEFAULT_CHUNK_RUNS
    # fault identification beside the routes: per segment, on the same realizations (test level --alpha)
    setup, why_not = _identify.setup_or_reason(sc.nominal, args)
    ident = None
    parallel = args.workers > 1 or args.scheduler is not None
    if setup is not None and not parallel:
        from ..studies.identification_diagnosis import IdentificationTally

        ident = IdentificationTally(sc, setup, alpha=args.alpha, confidence=args.confidence)
    if parallel:  # simulation and filters on workers: same figures
        from ..plants.simulate import simulate
        from ..studies.diagnosis_parallel import diagnose_parallel

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
            ident = tallies.pop()  # the identification tally comes last
        if args.record is not None:
            first = simulate(sc, 1, args.seed)
    else:
        chunks = iter_simulations(sc, args.runs, args.seed, chunk_runs=min(chunk, args.runs))
        tallies = [ChatteringTally(sc, threshold) if m == "chattering" else ModeTally(sc, m) for m in methods]
        first, sim_s = _serial(args, sc, [*tallies, *([ident] if ident is not None else [])], chunks, outputs)
    results = [t.result(info) if isinstance(t, ChatteringTally) else t.result() for t in tallies]
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
        from ..online.diagnosis_log import record_diagnosis

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
    _identify.print_diagnosis(ident_doc)
    if recording is not None:
        print(f"recording: {recording} (open with `chatterspec replay {recording}` or `rerun {recording}`)")
    written.finish()
    return 0


def _serial(
    args: argparse.Namespace, sc: object, tallies: list, chunks: object, outputs: dict
) -> tuple[object, float]:
    """The in-process loop over chunks: realization 0 (for --record, else None) and the simulation time."""
    from ..progress import Progress
    from ..studies.mode_diagnosis import ModeTally

    first, sim_s = None, 0.0
    with Progress(args.runs, "diagnose", enabled=False if args.no_progress else None) as bar:
        while True:
            t0 = time.perf_counter()
            sim = next(chunks, None)  # type: ignore[call-overload]
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


def _print_table(sc: object, args: argparse.Namespace, results: list) -> None:
    from ..figures.plot_diagnosis import diagnosis_rows

    print(f"diagnosis on {sc.name}: {args.runs} runs, seed {args.seed}")  # type: ignore[attr-defined]
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
