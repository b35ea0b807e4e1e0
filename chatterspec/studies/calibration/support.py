"""Can a calibration's number of healthy runs support its alpha? The minimum, and the refusal.

An empirical threshold is the order statistic of rank ``ceil(n (1 - alpha))`` of ``n`` healthy values
(:func:`~chatterspec.studies.intervals.quantile_ci_ranks`). A new healthy record exceeds the order
statistic of rank ``r`` with probability ``(n + 1 - r) / (n + 1)`` on average (the values are exchangeable).
With ``n + 1 < 1 / alpha`` the rank is ``n`` -- the threshold is the sample maximum -- and that
probability is ``1 / (n + 1) > alpha``: the calibration cannot deliver the alpha it claims (5 runs at
alpha = 0.001 flag about 1 healthy record in 6). Hence the minimum

    n_min = ceil(1 / alpha) - 1                          (expected false-alarm rate <= alpha)

and, for a bounded upper end of the two-sided order-statistic interval at level ``c``
(``P(all n values below the quantile) = (1 - alpha)^n <= (1 - c) / 2``),

    n_bounded = ceil(log((1 - c) / 2) / log(1 - alpha)).

The record family-wise threshold (``detect --calibration``) counts runs; the per-frame threshold
(``monitor`` / ``diagnose --calibration``) pools the frames of every run, of which only the
non-overlapping ones count as independent (as the calibration's own interval does), so it needs
``n_min / frames_eff`` runs. The functions here are pure; the command line refuses a calibration
for a use it cannot support (``calibrate`` before computing, the loaders when a file is used).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Literal

from ...errors import CalibrationMismatchError
from ...jsonout import fields_dict

if TYPE_CHECKING:  # pragma: no cover
    from .result import Calibration

__all__ = ["Support", "calibration_support", "min_runs", "require_support", "support_for"]

Use = Literal["detect", "monitor"]


def min_runs(alpha: float, per_run: int = 1) -> int:
    """Fewest runs whose threshold has an expected false-alarm rate <= ``alpha`` (module docstring).

    Parameters
    ----------
    alpha : float
        Nominal false-alarm probability in (0, 1).
    per_run : int
        Independent values per run (1 for the record threshold; the non-overlapping STFT frames of a
        record for the per-frame threshold).
    """
    return max(1, math.ceil((math.ceil(1.0 / alpha) - 1) / per_run))


def min_runs_bounded(alpha: float, confidence: float, per_run: int = 1) -> int:
    """Fewest runs for which the ``confidence`` order-statistic interval has a finite upper end."""
    return max(1, math.ceil(math.log((1.0 - confidence) / 2.0) / math.log1p(-alpha) / per_run))


@dataclass(frozen=True)
class Support:
    """Whether ``runs`` healthy runs support ``alpha`` for one use of a calibration.

    Attributes
    ----------
    use : {"detect", "monitor"}
        ``detect``: the record family-wise threshold; ``monitor``: the per-frame family-wise one.
    runs : int
        Healthy runs of the calibration.
    alpha : float
        Its nominal false-alarm probability (per record or per frame).
    per_run : int
        Independent values per run (1, or the non-overlapping frames of a record).
    min_runs : int
        Fewest runs whose threshold's expected false-alarm rate is <= alpha.
    min_runs_bounded : int
        Fewest runs for a bounded interval at the calibration's confidence.
    """

    use: Use
    runs: int
    alpha: float
    per_run: int
    min_runs: int
    min_runs_bounded: int

    @property
    def supported(self) -> bool:
        """Whether the runs reach the minimum the calibration needs."""
        return self.runs >= self.min_runs

    @property
    def expected_rate(self) -> float:
        """Expected false-alarm rate of the threshold when it is the sample maximum (unsupported case)."""
        return 1.0 / (self.runs * self.per_run + 1)

    def message(self) -> str:
        """Why the runs do not support alpha, and the minimum."""
        what = "record" if self.use == "detect" else "frame"
        values = f"{self.runs} runs" if self.per_run == 1 else f"{self.runs} runs x {self.per_run} frames"
        return (
            f"{self.runs} healthy runs cannot support alpha = {self.alpha:g} per {what}: the threshold "
            f"is the largest of {values}, which a healthy {what} exceeds with probability "
            f"{self.expected_rate:.2g} on average; calibrate with --runs >= {self.min_runs} "
            f"({self.min_runs_bounded} for a bounded interval)"
        )

    def to_dict(self) -> dict[str, object]:
        """The fields as a JSON-ready dict (what the JSON outputs print)."""
        return fields_dict(self, ("supported", "runs", "min_runs", "min_runs_bounded"))


def support_for(use: Use, runs: int, alpha: float, confidence: float, per_run: int = 1) -> Support:
    """:class:`Support` of ``runs`` healthy runs at ``alpha`` (``per_run`` independent values each).

    Parameters
    ----------
    use : {"detect", "monitor"}
        The record threshold, or the per-frame one.
    runs : int
        Healthy runs.
    alpha : float
        Nominal false-alarm probability in (0, 1).
    confidence : float
        Level of the order-statistic interval, for the bounded-interval minimum.
    per_run : int
        Independent values per run (1, or the non-overlapping frames of a record).
    """
    return Support(
        use=use,
        runs=int(runs),
        alpha=float(alpha),
        per_run=int(per_run),
        min_runs=min_runs(alpha, per_run),
        min_runs_bounded=min_runs_bounded(alpha, confidence, per_run),
    )


def frames_per_run(n_samples: int, window_s: float, dt: float) -> int:
    """Non-overlapping STFT windows in a record of ``n_samples`` samples (at least 1)."""
    from ...detection.spectral import STFTConfig

    W = STFTConfig(window_s=window_s).n_window(dt)
    return max(1, (int(n_samples) - W) // W + 1)


def calibration_support(cal: Calibration) -> dict[Use, Support]:
    """The :class:`Support` of a calibration for ``detect`` (record) and ``monitor`` (frames).

    Parameters
    ----------
    cal : Calibration
        A calibration (its runs, alpha, confidence, record length and STFT window).
    """
    per_frame = frames_per_run(cal.n_samples, float(cal.stft["window_s"]), cal.dt)
    return {
        "detect": support_for("detect", cal.runs, cal.alpha, cal.confidence),
        "monitor": support_for("monitor", cal.runs, cal.alpha, cal.confidence, per_frame),
    }


def require_support(cal: Calibration, use: Use, source: object) -> None:
    """Raise :class:`~chatterspec.errors.CalibrationMismatchError` if ``cal`` cannot support its alpha.

    Parameters
    ----------
    cal : Calibration
        A loaded calibration.
    use : {"detect", "monitor"}
        The threshold about to be used (record family-wise, or per-frame family-wise).
    source : str or Path
        The calibration file, for the message.
    """
    s = calibration_support(cal)[use]
    if not s.supported:
        raise CalibrationMismatchError(f"calibration file {str(source)!r}: {s.message()}")
