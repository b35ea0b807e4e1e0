"""The figures every diagnosis route reports: false alarms on the healthy time, detection delay per onset.

:class:`DiagnosisFigures` is the base of the results of the mode-based routes
(:class:`~chatterspec.studies.mode_diagnosis.ModeDiagnosis`: SMM-SVSF and IMM, a verdict per sample)
and of the chattering route (:class:`~chatterspec.studies.chattering_diagnosis.ChatteringDiagnosis`: a
verdict per STFT frame and channel). Each result adds what only its route has (modes, isolation delays
and the confusion matrix; or channels, segments and peak frequencies). :meth:`DiagnosisFigures.alarm_figures`
is the part of their ``describe()`` they share, so the JSON documents of ``chatterspec diagnose`` write
these figures with the same keys and the same NaN handling for every route.
"""

from __future__ import annotations

from dataclasses import dataclass

from ..jsonout import finite_or_none

__all__ = ["DiagnosisFigures"]


@dataclass(frozen=True, eq=False)
class DiagnosisFigures:
    """False-alarm and detection-delay figures of one diagnosis route on one set of realizations.

    Attributes
    ----------
    method : str
        The route (``"smm"``, ``"imm"`` or ``"chattering"``).
    runs : int
        Realizations.
    false_alarm_runs : int
        Runs with an alarm on the healthy time (family-wise per run).
    false_alarm_rate : float
        ``false_alarm_runs / runs``.
    false_alarm_ci : tuple of float
        99 % Clopper-Pearson interval of that rate.
    healthy_alarm_fraction : float
        Fraction of the healthy verdicts that are alarms (NaN when the scenario has no healthy time).
    onsets : tuple of float
        Fault onset times (s).
    detection_median, detection_p90 : tuple of float
        Median / 90th percentile over the detecting runs of the detection delay per onset (s; NaN when
        no run detects that onset).
    steps_per_second : float
        Realization-steps per second of the route.

    See Also
    --------
    chatterspec.studies.mode_diagnosis.ModeDiagnosis : the mode-based routes' result.
    chatterspec.studies.chattering_diagnosis.ChatteringDiagnosis : the chattering route's result.
    """

    method: str
    runs: int
    false_alarm_runs: int
    false_alarm_rate: float
    false_alarm_ci: tuple[float, float]
    healthy_alarm_fraction: float
    onsets: tuple[float, ...]
    detection_median: tuple[float, ...]
    detection_p90: tuple[float, ...]
    steps_per_second: float

    def alarm_figures(self) -> dict[str, object]:
        """The false-alarm and detection-delay block of ``describe()``, JSON-ready (NaN -> None).

        Returns
        -------
        dict
            ``false_alarm_runs``, ``false_alarm_rate``, ``false_alarm_ci99``, ``healthy_alarm_fraction``,
            ``onsets_s``, ``detection_delay_median_s``, ``detection_delay_p90_s``, in that order.
        """
        return {
            "false_alarm_runs": self.false_alarm_runs,
            "false_alarm_rate": self.false_alarm_rate,
            "false_alarm_ci99": list(self.false_alarm_ci),
            "healthy_alarm_fraction": finite_or_none(self.healthy_alarm_fraction),
            "onsets_s": list(self.onsets),
            "detection_delay_median_s": [finite_or_none(v) for v in self.detection_median],
            "detection_delay_p90_s": [finite_or_none(v) for v in self.detection_p90],
        }
