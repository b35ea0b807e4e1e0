"""Regenerate the diagnosis figures under figures/:

* ``diagnosis_table_eha4.png``: the ``chatterspec diagnose eha4-leak-timeline --per-record`` table
  (chattering, SMM-SVSF and IMM-EKF on the same ``--runs`` realizations, each with its own rule; the
  comparison at one false-alarm budget is ``diagnose ... --plot``, ``figures/diagnosis_budget_*.png``);
* ``smm_mode_weights.png``: SMM-SVSF mode weights over time, mean over the runs (the SMM paper's Fig 5),
  with the true mode shaded;
* ``imm_confusion.png``: the IMM-EKF confusion matrix on ``eha4-imm-analogue`` (``--imm-runs`` runs;
  0 skips it).

Usage: ``python scripts/make_diagnosis_figures.py [--out figures] [--runs 100] [--seed 0] [--imm-runs 10]``
(about 30 s for the SMM scenario at 100 runs, plus a few seconds for the IMM analogue).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import chatterspec as cs
from chatterspec.figures.plot_diagnosis import (
    confusion_figure,
    diagnosis_rows,
    diagnosis_table_figure,
    mode_weights_figure,
)
from chatterspec.figures.plot_studies import save
from chatterspec.studies.diagnosis import calibrate_for_diagnosis, diagnose_chattering, diagnose_modes


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", default="figures")
    p.add_argument("--runs", type=int, default=100)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--imm-runs", type=int, default=10)
    args = p.parse_args()
    out = Path(args.out)
    sc = cs.scenario("eha4-leak-timeline")
    t0 = time.perf_counter()
    cal = calibrate_for_diagnosis(sc, args.seed)
    sim = cs.simulate(sc, runs=args.runs, seed=args.seed)
    chat = diagnose_chattering(sim, cal.threshold("frame-family-wise"))
    keep: dict = {}
    results = [chat, *diagnose_modes(sim, ("smm", "imm"), keep=keep)]
    wall = time.perf_counter() - t0
    header, rows = diagnosis_rows(results)
    print(" | ".join(header))
    for r in rows:
        print(" | ".join(r))
    print(f"wall time {wall:.1f} s (calibration included)")
    title = (
        f"diagnose {sc.name} per record: chattering, SMM-SVSF, IMM; {args.runs} runs, seed {args.seed} "
        "(chattering threshold: 500 healthy runs)"
    )
    print(save(diagnosis_table_figure(results, title=title), out / "diagnosis_table_eha4.png"))
    t, mu, modes = keep["smm"]
    true = sc.filter_settings.mode_index(sc)[1:]
    mw_title = f"SMM-SVSF mode weights on {sc.name}, mean over {args.runs} runs (seed {args.seed})"
    print(
        save(mode_weights_figure(t, mu, modes, true_mode=true, title=mw_title), out / "smm_mode_weights.png")
    )
    if args.imm_runs > 0:
        imm_sc = cs.scenario("eha4-imm-analogue")
        (imm,) = diagnose_modes(cs.simulate(imm_sc, runs=args.imm_runs, seed=args.seed), ("imm",))
        title = f"IMM-EKF on {imm_sc.name} ({args.imm_runs} runs): mean mode probability [%]"
        print(save(confusion_figure(imm.confusion, imm.modes, title=title), out / "imm_confusion.png"))


if __name__ == "__main__":
    main()
