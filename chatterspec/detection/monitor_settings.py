"""The detector settings of the online monitor, :class:`MonitorSettings`.

In the detection layer because the alarm studies (:mod:`chatterspec.studies.alarm_budget`,
:mod:`chatterspec.studies.alarm_budget`, the diagnosis routes) compute with the same settings
without the online monitor; :mod:`chatterspec.online.monitor` re-exports it (its documented home).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Literal, cast

import numpy as np

from .._validate import finite_array, open_unit
from ..detection.alarm_calibration import RuleCalibration
from ..detection.alarms import AlarmRule, is_rule
from ..detection.spectral import STFTConfig
from ..detection.thresholds import Threshold, check_band
from ..errors import ParameterError

__all__ = ["MonitorSettings"]


@dataclass(frozen=True)
class MonitorSettings:
    """Detector settings of the online monitor.

    Parameters
    ----------
    stft : STFTConfig
        Window and hop (default 1 s Hamming, 0.2 s hop).
    alpha : float
        Per-frame false-alarm probability (0 < alpha < 1).
    correction : {"bonferroni", "sidak", "none"}
        Family-wise correction over the tested bins of a frame.
    gamma : float
        SVSF convergence rate (both filters).
    psi : tuple of float, optional
        Smoothing boundary layer per output. When given, the ``sat`` SVSF runs
        too (its estimate is reported and the boundary drawn next to the
        chattering); ``None`` runs only the auxiliary filter.
    threshold : Threshold, optional
        Per-frame threshold to use instead of the analytic
        :func:`~chatterspec.detection.thresholds.frame_threshold`, e.g. the empirical one of
        a saved calibration, ``load_calibration(...).threshold("frame-family-wise")``
        (then ``alpha`` and ``correction`` are ignored). It must cover the STFT
        frequencies of ``stft``.
    band : (float, float), optional
        ``(lo, hi)`` in Hz: test only the frame bins with ``lo <= f <= hi`` (beyond the
        paper, see :mod:`chatterspec.detection.thresholds`); the correction counts only
        them. With ``threshold`` given, that threshold is restricted to the band
        (:meth:`~chatterspec.detection.thresholds.Threshold.restricted`: its level is then
        conservative). ``None`` (default): every bin but DC and Nyquist.
    rule : AlarmRule, optional
        The alarm rule (:mod:`chatterspec.detection.alarms`) that turns the frame score
        (``-log`` of the frame's p-value, :mod:`chatterspec.detection.frame_score`) into
        fault-start / fault-end events, with its threshold set (e.g. by
        :func:`chatterspec.studies.alarm_budget.alarm_settings` for a false-alarm budget).
        ``None`` (default): the per-frame rule at ``alpha``, events where the per-frame
        verdict (``FrameBlock.flags``) changes, as before the alarm layer.
    budget : RuleCalibration, optional
        How ``rule``'s threshold was set for a budget in false alarms per hour (reported in
        events, summaries and recordings); its ``rule`` must be ``rule``.
    """

    stft: STFTConfig = field(default_factory=STFTConfig)
    alpha: float = 1e-3
    correction: Literal["none", "bonferroni", "sidak"] = "bonferroni"
    gamma: float = 0.1
    psi: tuple[float, ...] | None = None
    threshold: Threshold | None = None
    band: tuple[float, float] | None = None
    rule: AlarmRule | None = None
    budget: RuleCalibration | None = None

    def __post_init__(self) -> None:
        if self.rule is not None and not is_rule(self.rule):
            raise ParameterError(f"rule must be an alarm rule; got {type(self.rule).__name__}")
        if self.budget is not None:
            if not isinstance(self.budget, RuleCalibration):
                raise ParameterError(f"budget must be a RuleCalibration; got {type(self.budget).__name__}")
            if self.budget.rule != self.rule:
                raise ParameterError(
                    f"budget was calibrated for {self.budget.rule.to_dict()}; the rule is "
                    f"{None if self.rule is None else self.rule.to_dict()}"
                )
        if self.band is not None:
            object.__setattr__(self, "band", check_band(self.band))
        if not isinstance(self.stft, STFTConfig):
            raise ParameterError(f"stft must be an STFTConfig; got {type(self.stft).__name__}")
        object.__setattr__(self, "alpha", open_unit("alpha", self.alpha))
        object.__setattr__(self, "gamma", open_unit("gamma", self.gamma))
        if self.correction not in ("none", "bonferroni", "sidak"):
            raise ParameterError(
                f"correction must be 'none', 'bonferroni' or 'sidak'; got {self.correction!r}"
            )
        if self.threshold is not None and not isinstance(self.threshold, Threshold):
            raise ParameterError(f"threshold must be a Threshold; got {type(self.threshold).__name__}")
        if self.psi is not None:
            psi = tuple(float(p) for p in np.atleast_1d(finite_array("psi", self.psi, ndim=(0, 1))))
            if any(p <= 0 for p in psi):
                raise ParameterError(f"psi must be > 0; got {list(psi)}")
            object.__setattr__(self, "psi", psi)

    @classmethod
    def from_detector(
        cls,
        detector: Mapping[str, Any],
        *,
        gamma: float = 0.1,
        psi: Sequence[float] | None = None,
        alpha: float | None = None,
        band: tuple[float, float] | None = None,
    ) -> MonitorSettings:
        """The settings a model file's ``[detector]`` table gives the monitor (no alarm rule yet).

        Parameters
        ----------
        detector : mapping
            ``ModelSpec.detector``: ``window_s``, ``hop_s`` (s), ``window``, ``alpha``, ``correction``,
            ``band`` (Hz); missing keys take the defaults (1 s Hamming, 0.2 s hop, 0.001, Bonferroni).
        gamma : float
            SVSF convergence rate (the file's ``[svsf] gamma``).
        psi : sequence of float, optional
            Boundary layer per output (None: the auxiliary filter only).
        alpha : float, optional
            Per-frame level overriding the table's.
        band : (float, float), optional
            Tested band (Hz) overriding the table's.
        """
        stft = STFTConfig(
            window_s=float(detector.get("window_s", 1.0)),
            hop_s=float(detector.get("hop_s", 0.2)),
            window=str(detector.get("window", "hamming")),
        )
        return cls(
            stft=stft,
            alpha=float(alpha if alpha is not None else detector.get("alpha", 1e-3)),
            correction=cast(
                Literal["none", "bonferroni", "sidak"], str(detector.get("correction", "bonferroni"))
            ),  # checked by __post_init__
            gamma=gamma,
            psi=None if psi is None else tuple(float(x) for x in psi),
            band=band or detector.get("band"),
        )

    @property
    def false_alarms_per_hour(self) -> float | None:
        """The budget of :attr:`budget` (alarm starts per hour, all channels), or None."""
        return None if self.budget is None else self.budget.false_alarms_per_hour
