"""``chatterspec diagnose NAME [--methods smm,imm] [--runs N] [--seed S] [--json]``: fault diagnosis by mode
probabilities, every method on the same realizations (issue 9 item 6, mode-based methods only).

The chattering route on the nonlinear plant (issue 9 item 5) is not available yet: ``--methods chattering``
is rejected with a message saying so. ``--record`` (Rerun) is not implemented either.
"""

from __future__ import annotations

import argparse

from ..errors import ParameterError
from ._common import positive_int_arg, print_json


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "diagnose",
        help="fault diagnosis by mode probabilities (SMM-SVSF, IMM) on the same realizations",
        description="Runs each method on the same seeded realizations and reports false alarms on the "
        "healthy samples (family-wise per run, 99%% Clopper-Pearson), detection and isolation delays per "
        "fault onset (median, 90th percentile), the confusion matrix and the cost.",
    )
    p.add_argument(
        "name", metavar="NAME", help="scenario with filter_settings modes (e.g. eha4-leak-timeline)"
    )
    p.add_argument(
        "--methods",
        default=None,
        help="comma-separated subset of smm,imm (default: those the scenario's filter_settings support)",
    )
    p.add_argument("--runs", type=positive_int_arg, default=10, help="realizations (default 10)")
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    p.add_argument("--json", action="store_true", help="print one JSON document")
    p.set_defaults(func=run)


def _methods(text: str | None, fs: object) -> tuple[str, ...]:
    from ..studies.mode_diagnosis import METHODS

    if text is None:
        out = []
        if fs.psi is not None:  # type: ignore[attr-defined]
            out.append("smm")
        if fs.transition_matrix is not None:  # type: ignore[attr-defined]
            out.append("imm")
        return tuple(out)
    names = tuple(s.strip() for s in text.split(",") if s.strip())
    for name in names:
        if name == "chattering":
            raise ParameterError(
                "the chattering method on the nonlinear plant is not available yet (issue 9 item 5); "
                f"use --methods {','.join(METHODS)}"
            )
        if name not in METHODS:
            raise ParameterError(
                f"--methods takes a comma-separated subset of {','.join(METHODS)}; got {name!r}"
            )
    return names


def run(args: argparse.Namespace) -> int:
    from ..plants.scenarios import scenario
    from ..plants.simulate import simulate
    from ..studies.mode_diagnosis import diagnose_modes

    sc = scenario(args.name)
    fs = sc.filter_settings
    if fs is None or not fs.modes:
        raise ParameterError(
            f"scenario {sc.name!r} names no filter modes; try eha4-leak-timeline or eha4-imm-analogue"
        )
    methods = _methods(args.methods, fs)
    sim = simulate(sc, runs=args.runs, seed=args.seed)
    results = diagnose_modes(sim, methods)
    if args.json:
        print_json(
            {
                "scenario": sc.name,
                "runs": args.runs,
                "seed": args.seed,
                "methods": [r.describe() for r in results],
            }
        )
        return 0
    print(f"diagnosis on {sc.name}: {args.runs} runs, seed {args.seed}; modes {', '.join(fs.modes)}")
    print(
        f"{'method':<7} {'FA runs [99% CI]':<24} {'healthy in alarm':>16}  {'onset':>6} "
        f"{'detect med/p90 [ms]':>20} {'isolate med/p90 [ms]':>21} {'missed':>6}  {'steps/s':>9}"
    )
    for r in results:
        fa = f"{r.false_alarm_rate:.3f} [{r.false_alarm_ci[0]:.3f}, {r.false_alarm_ci[1]:.3f}]"
        for i, onset in enumerate(r.onsets):
            head = f"{r.method:<7} {fa:<24} {r.healthy_alarm_fraction:>16.4f}" if i == 0 else " " * 49
            print(
                f"{head}  {onset:>6.2f} "
                f"{1e3 * r.detection_median[i]:>9.2f}/{1e3 * r.detection_p90[i]:<10.2f} "
                f"{1e3 * r.isolation_median[i]:>10.2f}/{1e3 * r.isolation_p90[i]:<10.2f} {r.missed[i]:>6}"
                + (f"  {r.steps_per_second:>9.0f}" if i == 0 else "")
            )
        diag = ", ".join(f"{m} {r.confusion[j, j]:.1f}%" for j, m in enumerate(r.modes))
        print(f"        confusion diagonal: {diag}")
    return 0
