"""``chatterspec diagnose --per-record``: each route with its own rule, as the papers report them.

* ``smm``, ``imm``: alarm while the most probable mode is a fault mode (the argmax rule);
* ``chattering``: the per-frame, family-wise threshold at ``--alpha`` (calibrated on healthy runs
  of the scenario's healthy version, or read from ``--calibration FILE``).

False alarms are family-wise per run (99 % Clopper-Pearson), on the healthy segments. These rules do
not alarm equally often, so the delays of this table cannot rank the routes; ``diagnose`` without
``--per-record`` compares them at one false-alarm budget (:mod:`chatterspec.cli.diagnose`).

The runs are simulated and diagnosed in chunks of ``--chunk-runs`` (default 64): only per-run figures
are kept, so the memory does not grow with ``--runs``, and the output does not depend on the chunking;
with ``--workers`` / ``--scheduler`` the chunks run on worker processes
(:func:`~chatterspec.studies.diagnosis_parallel.diagnose_parallel`), with the same figures.
"""

from __future__ import annotations

import argparse
import math
import time
from typing import TYPE_CHECKING, Any, cast

from . import _identify
from ._common import Outputs, print_json

if TYPE_CHECKING:  # pragma: no cover
    from collections.abc import Iterator

    from ..detection.thresholds import Threshold
    from ..plants.scenarios import Scenario
    from ..plants.simulate import Simulation


def chattering_threshold(args: argparse.Namespace, sc: Scenario) -> tuple[Threshold, dict[str, Any]]:
    """The chattering route's per-frame threshold at ``--alpha`` and its provenance.

    From ``--calibration FILE`` (refused without enough runs for the per-frame threshold), or
    calibrated now on ``--calibration-runs`` healthy runs of the scenario's healthy version
    (:func:`~chatterspec.studies.chattering_diagnosis.calibrate_for_diagnosis`, on ``--workers`` /
    ``--scheduler``). Its expected spectrum is also the healthy law of the frame score of a nonlinear
    model at a budget.
    """
    from ..detection.spectral import STFTConfig

    config = STFTConfig()
    if args.calibration is not None:
        from ..studies.calibration import load_calibration
        from ..studies.calibration_support import require_support

        cal = load_calibration(args.calibration, sc.nominal, config=config)
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
            from ..studies.identification_diagnosis import IdentificationTally

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
    _identify.print_diagnosis(ident_doc)
    if recording is not None:
        print(f"recording: {recording} (open with `chatterspec replay {recording}` or `rerun {recording}`)")
    written.finish()
    return 0


def _serial(
    args: argparse.Namespace, sc: Scenario, tallies: list, chunks: Iterator[Simulation], outputs: dict
) -> tuple[Simulation | None, float]:
    """The in-process loop over chunks: realization 0 (for --record, else None) and the simulation time."""
    from ..progress import Progress
    from ..studies.mode_diagnosis import ModeTally

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
