"""The record-level detection report, :class:`DetectionReport` (re-exported by
:mod:`chatterspec.detection.detect`, which makes it)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from .._repr import short_repr
from .thresholds import Threshold
from .verdicts import ChannelVerdict, FrameDetection, SpectrumDetection

__all__ = ["DetectionReport"]


@dataclass(frozen=True, eq=False)
class DetectionReport:
    """Detection of a :class:`~chatterspec.detection.pipeline.ChatteringRecord` (or a stream of chunks).

    Attributes
    ----------
    scenario : str or None
        Scenario name.
    channels : tuple of str
    runs : int
    per_run : SpectrumDetection
        ``(runs, m)`` verdict arrays, one per realization, against the single-record
        threshold (``per_run.threshold``).
    averaged : SpectrumDetection or None
        ``(m,)`` verdict of the Monte Carlo averaged spectrum (Fig 6) against the
        averaged ``exact`` threshold with K = runs (``averaged.threshold``), whatever
        the single-record rule; None when runs == 1.
    frames : FrameDetection or None
        STFT detection of run 0 (multi-segment scenarios, or when requested).
    """

    __repr__ = short_repr  # shapes and key figures, never whole arrays
    _repr_extra = ("detected",)

    scenario: str | None
    channels: tuple[str, ...]
    runs: int
    per_run: SpectrumDetection
    averaged: SpectrumDetection | None = None
    frames: FrameDetection | None = field(default=None)

    @property
    def verdicts(self) -> tuple[ChannelVerdict, ...]:
        """Single-run verdicts (runs == 1) or the averaged-spectrum verdicts (runs > 1)."""
        if self.averaged is not None:
            return self.averaged.verdicts()
        return self.per_run.verdicts(0)

    @property
    def detected(self) -> bool:
        """Any channel of :attr:`verdicts` detected."""
        return any(v.detected for v in self.verdicts)

    @property
    def detection_rate(self) -> dict[str, float]:
        """Fraction of the runs detected, per channel (single-record threshold)."""
        return {c: float(r) for c, r in zip(self.channels, self.per_run.detection_rate, strict=True)}

    def table(self) -> str:
        """The report as the text table ``chatterspec detect`` prints (one row per channel).

        Returns
        -------
        str
            See :func:`chatterspec.detection.report_text.detection_table`.
        """
        from .report_text import detection_table

        return detection_table(self.to_dict())

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready report.

        Keys: ``scenario``, ``runs``, ``detected``, ``threshold`` (the single-record
        threshold: kind, alpha, alpha_meaning, correction, band, n_tested,
        description), ``channels`` (list of ``{"channel", "detected", "peak_hz",
        "most_significant_hz", "peak_ratio", "excess_power", "dc_ratio",
        "ratio_threshold"}``: the single run, or with ``runs > 1`` the
        averaged-spectrum verdict plus ``"detection_rate"``, the fraction of single
        runs detected by ``threshold``), ``"averaged"`` (bool), with ``runs > 1``
        ``"averaged_threshold"`` (same keys plus ``records``), ``"verdict_threshold"``
        (``"threshold"`` or ``"averaged_threshold"``: the one ``detected``,
        ``peak_ratio`` and ``most_significant_hz`` refer to; ``ratio_threshold``
        repeats it per channel) and, when the STFT was run, ``"intervals"`` (list of
        ``{"channel", "onset_s", "offset_s"}`` for run 0, channel ``"any"`` included).
        """
        chans = []
        rates = self.detection_rate
        which = "averaged_threshold" if self.averaged is not None else "threshold"
        for v in self.verdicts:
            d = v.to_dict()
            d["ratio_threshold"] = which
            if self.runs > 1:
                d["detection_rate"] = rates[v.channel]
            chans.append(d)
        out: dict[str, object] = {
            "scenario": self.scenario,
            "runs": self.runs,
            "detected": bool(self.detected),
            "averaged": self.averaged is not None,
            "verdict_threshold": which,
            "threshold": _threshold_dict(self.per_run.threshold),
            "channels": chans,
        }
        if self.averaged is not None:
            out["averaged_threshold"] = {**_threshold_dict(self.averaged.threshold), "records": self.runs}
        if self.frames is not None:
            out["intervals"] = [
                {"channel": ch, "onset_s": on, "offset_s": off}
                for ch, ivs in self.frames.intervals.items()
                for on, off in ivs
            ]
        return out


def _threshold_dict(th: Threshold) -> dict[str, object]:
    return {
        "kind": th.kind,
        "alpha": th.alpha,
        "alpha_meaning": th.alpha_meaning,
        "correction": th.correction,
        "band": None if th.band is None else list(th.band),
        "n_tested": th.n_tested,
        "description": th.describe(),
    }
