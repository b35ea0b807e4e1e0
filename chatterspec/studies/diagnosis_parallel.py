"""``chatterspec diagnose --workers N``: the heavy part of each chunk on worker processes, the same figures.

Each chunk of realizations is simulated and run through every method's filter on a worker
(:meth:`~chatterspec.studies.chattering_diagnosis.ChatteringTally.compute`,
:meth:`~chatterspec.studies.mode_diagnosis.ModeTally.compute`); the calling process folds the chunks
**in chunk order** into the tallies (``absorb``), exactly the steps of the serial loop. Realization
``r``'s numbers do not depend on the chunking, and the running sums of the tallies see the same rows
in the same order, so every figure is the serial one, bit for bit (``steps/s`` aside: it is the
filters' own time, summed over the workers). Memory: at most ``2 x workers`` chunks in flight, each
sending back its mode probabilities (``runs x T x modes`` floats, ~14 MB for 64 runs of the 9 s EHA).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Unpack

import numpy as np

from ..montecarlo import Execution, ExecutionOptions
from ..plants.simulate import iter_simulations
from .chattering_diagnosis import ChatteringTally
from .mode_diagnosis import ModeTally

if TYPE_CHECKING:  # pragma: no cover
    from ..detection.identification import IdentificationSetup
    from ..detection.thresholds import Threshold
    from ..plants.scenarios import Scenario
    from .identification_diagnosis import IdentificationTally

__all__ = ["diagnose_parallel"]


def _tallies(
    scenario: Scenario,
    methods: tuple[str, ...],
    threshold: Threshold | None,
    identification: tuple[IdentificationSetup, float, float] | None = None,
) -> list[ChatteringTally | ModeTally | IdentificationTally]:
    def chattering() -> ChatteringTally:
        assert threshold is not None  # (given with the chattering route)
        return ChatteringTally(scenario, threshold)

    out: list[ChatteringTally | ModeTally | IdentificationTally] = [
        chattering() if m == "chattering" else ModeTally(scenario, m) for m in methods
    ]
    if identification is not None:  # (setup, alpha, confidence): fault identification per segment, last
        from .identification_diagnosis import IdentificationTally

        setup, alpha, confidence = identification
        out.append(IdentificationTally(scenario, setup, alpha=alpha, confidence=confidence))
    return out


@dataclass(frozen=True, eq=False)
class _DiagnoseStudy:
    """A :class:`~chatterspec.montecarlo.Study` whose accumulator is the tallies themselves."""

    scenario: Scenario
    methods: tuple[str, ...]
    threshold: Threshold | None
    keep: bool
    identification: tuple[IdentificationSetup, float, float] | None = None

    def run_chunk(self, first_run: int, runs: int, seed: np.random.SeedSequence) -> Any:
        (sim,) = iter_simulations(self.scenario, runs, seed, chunk_runs=runs, first_run=first_run)
        tallies = _tallies(self.scenario, self.methods, self.threshold, self.identification)
        return sim.t, [tally.compute(sim) for tally in tallies]

    def reduce(self, acc: Any, part: Any) -> Any:
        if acc is None:
            acc = {
                "tallies": _tallies(self.scenario, self.methods, self.threshold, self.identification),
                "keep": {},
            }
        t, computed = part
        for tally, c in zip(acc["tallies"], computed, strict=True):
            if isinstance(tally, ModeTally):
                tally.absorb(c, keep=acc["keep"] if self.keep else None, keep_runs=1)
            else:
                tally.absorb(t, c)
        return acc


def diagnose_parallel(
    scenario: Scenario,
    methods: tuple[str, ...],
    threshold: Threshold | None,
    runs: int,
    seed: int,
    *,
    keep: bool = False,
    identification: tuple[IdentificationSetup, float, float] | None = None,
    **execution: Unpack[ExecutionOptions],
) -> tuple[list[ChatteringTally | ModeTally | IdentificationTally], dict[str, Any]]:
    """The tallies of ``methods`` over ``runs`` realizations, computed on workers (same figures as serial).

    Parameters
    ----------
    scenario : Scenario
        The diagnosed scenario.
    methods : tuple of str
        ``"chattering"``, ``"smm"``, ``"imm"`` (as ``chatterspec diagnose --methods``).
    threshold : Threshold or None
        The chattering route's per-frame threshold (None without that route).
    runs, seed : int
        Realizations and root seed.
    keep : bool
        Keep realization 0's mode probabilities per mode method (for ``--record``).
    identification : (IdentificationSetup, float, float), optional
        ``(setup, alpha, confidence)``: fault identification per segment too
        (:class:`~chatterspec.studies.identification_diagnosis.IdentificationTally`), returned last.
    **execution
        ``workers``, ``scheduler``, ``chunk_runs``, ``progress``: how the runs execute
        (:class:`~chatterspec.montecarlo.Execution`).

    Returns
    -------
    (list of tallies, dict)
        The tallies in ``methods`` order (call ``result()``), and the kept mode probabilities.
    """

    ex = Execution(**execution)
    study = _DiagnoseStudy(scenario, tuple(methods), threshold, keep, identification)
    acc = ex.run(study, runs, seed, "diagnose")
    return acc["tallies"], acc["keep"]
