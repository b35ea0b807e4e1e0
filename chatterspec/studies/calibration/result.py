"""The result of a threshold calibration, :class:`Calibration`: its file and the runs it needs.

:func:`~chatterspec.studies.calibration.thresholds.calibrate` computes it (analytic thresholds;
empirical ones of a nonlinear model by
:func:`~chatterspec.studies.calibration.thresholds.calibrate_empirical`);
:mod:`~chatterspec.studies.calibration.recorded` reads it from a healthy recording.

File format
    A ``Calibration`` as JSON or as ``.npz`` arrays with a JSON header.
    :meth:`Calibration.to_dict` and :meth:`Calibration.save` call :func:`calibration_dict` and
    :func:`save_calibration`; :func:`read_calibration` reads a file back into the fields that
    :func:`load_calibration` turns into a checked ``Calibration``. Version
    :data:`CALIBRATION_VERSION` of format :data:`CALIBRATION_FORMAT`.

"""

from __future__ import annotations

import json
import math
import zipfile
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np
import scipy.stats

from ..._repr import short_repr
from ..._validate import readonly
from ...detection.alarms.calibration import RuleCalibration
from ...detection.spectral import STFTConfig
from ...detection.thresholds import Correction, Threshold
from ...errors import CalibrationMismatchError, DataFileError, ParameterError
from ...plants.nonlinear import Model
from ..intervals import QuantileEstimate, _none_to_inf

__all__ = [
    "CALIBRATION_FORMAT",
    "CALIBRATION_VERSION",
    "Calibration",
    "calibration_dict",
    "load_calibration",
    "read_calibration",
    "save_calibration",
]


# --------------------------------------------------------------------------- calibration
@dataclass(frozen=True, eq=False)
class Calibration:
    """Analytic and empirical thresholds of one healthy model (result of :func:`calibrate`).

    Thresholds on the power are ``E[S] * factor``; the arrays below are the
    factors (normalized thresholds) unless stated otherwise.

    Attributes
    ----------
    scenario, model_name, model_fingerprint : str
        What was calibrated (the fingerprint guards :meth:`check`).
    dt : float
    n_samples : int
        Record length N of the periodogram.
    stft : dict
        ``window_s``, ``hop_s``, ``window`` of the per-frame calibration.
    alpha : float
    runs : int
    seed : int or None
    confidence : float
        Level of every interval.
    channels : tuple of str
    freqs_hz : (bins,) array
    tested : (bins,) bool array
        Bins of the detector (DC and Nyquist excluded).
    expected : (bins, m) array
        Exact expected healthy spectrum.
    analytic : dict of str -> (bins, m) array
        ``paper``, ``exact`` (per-bin), ``exact-bonferroni``, ``exact-sidak`` thresholds (power units).
    per_bin, per_bin_low, per_bin_high : (bins, m) arrays
        Empirical per-bin ``(1 - alpha)``-quantile of ``S / E[S]`` and its interval.
    family_wise : tuple of QuantileEstimate
        Per channel: ``(1 - alpha)``-quantile of ``max_tested S / E[S]``.
    family_wise_analytic : dict of str -> float
        Bonferroni and Sidak factors ``chi2.isf(a, 2) / 2``.
    frame_freqs_hz, frame_tested, frame_expected, frame_analytic, per_frame, per_frame_low, per_frame_high
        The same for STFT frames (quantiles pooled over frames).
    frame_family_wise : tuple of QuantileEstimate
        Per channel: ``(1 - alpha)``-quantile over frames of ``max_tested S / E[S]``
        (the empirical per-frame threshold of the live monitor, family-wise over
        the bins of one frame); its interval counts only non-overlapping frames
        as independent.
    normalization : {"analytic", "empirical"}
        ``expected``/``frame_expected`` are the closed-form spectrum (linear model, eq 56) or an
        estimate from healthy pilot runs (nonlinear model; :func:`~.thresholds.calibrate_empirical`; then
        ``analytic``, ``frame_analytic`` and ``family_wise_analytic`` are empty).
    normalization_info : dict
        How an empirical normalization was estimated (pilot runs, smoothing); empty otherwise.
    tails : dict
        How the empirical quantiles were read: ``method`` ``"exact"`` (order statistics of the
        kept top-k tails) or ``"histogram"`` (bounded memory, :mod:`~.healthy`, with
        ``pilot_runs``, ``fine_rel_width``, ``outside_window``); ``budget_bytes`` and the
        ``exact_bytes`` the exact tails would need. Empty for files of older versions.
    alarm : RuleCalibration or None
        The monitor's alarm rule calibrated for a false-alarm budget (rule, threshold, budget,
        frames per hour; :mod:`chatterspec.studies.alarm_budget`), when made with ``--rule``.
    source : dict
        Where the healthy data came from when they were recorded, not simulated
        (:mod:`~chatterspec.studies.calibration.recorded`: data file name and SHA-256, time span,
        samples, frames, records); empty for a simulated calibration.
    """

    __repr__ = short_repr  # shapes and key figures, never whole arrays

    scenario: str
    model_name: str
    model_fingerprint: str
    dt: float
    n_samples: int
    stft: dict[str, Any]
    alpha: float
    runs: int
    seed: int | None
    confidence: float
    channels: tuple[str, ...]
    freqs_hz: np.ndarray
    tested: np.ndarray
    expected: np.ndarray
    analytic: dict[str, np.ndarray]
    per_bin: np.ndarray
    per_bin_low: np.ndarray
    per_bin_high: np.ndarray
    family_wise: tuple[QuantileEstimate, ...]
    family_wise_analytic: dict[str, float]
    frame_freqs_hz: np.ndarray
    frame_tested: np.ndarray
    frame_expected: np.ndarray
    frame_analytic: dict[str, np.ndarray]
    per_frame: np.ndarray
    per_frame_low: np.ndarray
    per_frame_high: np.ndarray
    frame_family_wise: tuple[QuantileEstimate, ...] = ()
    normalization: str = "analytic"
    normalization_info: dict[str, Any] = field(default_factory=dict)
    tails: dict[str, Any] = field(default_factory=dict)
    alarm: RuleCalibration | None = None
    source: dict[str, Any] = field(default_factory=dict)

    # ---- derived
    @property
    def exact_factor(self) -> np.ndarray:
        """Analytic exact per-bin factor ``chi2.isf(alpha, nu) / nu`` per bin and channel."""
        return self.analytic["exact"] / self.expected

    def agreement(self) -> dict[str, Any]:
        """Does the analytic exact threshold fall inside the empirical intervals?

        Returns per-bin coverage (fraction of tested bins/channels whose
        analytic factor lies in the empirical interval), the number of misses
        and the largest miss count consistent with intervals of level
        ``confidence`` (binomial 0.999 quantile, bins treated as independent),
        and the family-wise check per channel. Empty for an empirical normalization.
        """
        if self.normalization == "empirical":
            return {}
        t = self.tested
        f = self.exact_factor[t]
        inside = (self.per_bin_low[t] <= f) & (f <= self.per_bin_high[t])
        n = inside.size
        misses = int(n - np.count_nonzero(inside))
        allowed = int(scipy.stats.binom.ppf(0.999, n, 1 - self.confidence))
        fw = [q.contains(self.family_wise_analytic["sidak"]) for q in self.family_wise]
        ft = self.frame_tested
        ff = (self.frame_analytic["frame"] / self.frame_expected)[ft]
        f_in = (self.per_frame_low[ft] <= ff) & (ff <= self.per_frame_high[ft])
        return {
            "per_bin_coverage": float(np.mean(inside)),
            "per_bin_misses": misses,
            "per_bin_tests": n,
            "per_bin_misses_allowed": allowed,
            "per_bin_agrees": misses <= allowed,
            "per_bin_median_ratio": float(np.median(self.per_bin[t] / self.exact_factor[t])),
            "family_wise_agrees": fw,
            "per_frame_coverage": float(np.mean(f_in)),
            "per_frame_median_ratio": float(
                np.median(self.per_frame[ft] / (self.frame_analytic["frame"] / self.frame_expected)[ft])
            ),
        }

    # ---- use as a threshold
    def check(self, model: Model, n_samples: int | None = None, config: STFTConfig | None = None) -> None:
        """Raise :class:`CalibrationMismatchError` (with the reason) unless this calibration fits.

        Checks the model fingerprint (matrices, noise covariances, dt), the
        record length and the STFT settings.
        """
        if model.fingerprint() != self.model_fingerprint:
            raise CalibrationMismatchError(
                f"calibration was made for model {self.model_name!r} (fingerprint "
                f"{self.model_fingerprint[:12]}); the model in use ({model.name!r}, fingerprint "
                f"{model.fingerprint()[:12]}) differs in A, B, C, Q, R or dt -- recalibrate it"
            )
        if not math.isclose(model.dt, self.dt, rel_tol=1e-12):
            raise CalibrationMismatchError(f"calibration dt = {self.dt} s; the model has dt = {model.dt} s")
        if n_samples is not None and int(n_samples) != self.n_samples:
            raise CalibrationMismatchError(
                f"calibration is for records of N = {self.n_samples} samples; got N = {n_samples}"
            )
        if config is not None:
            want = _stft_dict(config)
            if want != self.stft:
                raise CalibrationMismatchError(f"calibration STFT settings {self.stft} differ from {want}")

    def threshold(
        self, meaning: Literal["per-bin", "family-wise", "per-frame", "frame-family-wise"] = "family-wise"
    ) -> Threshold:
        """The empirical threshold as a :class:`~.thresholds.Threshold` (``kind="empirical"``).

        Parameters
        ----------
        meaning : {"family-wise", "per-bin", "per-frame", "frame-family-wise"}
            ``family-wise``: ``E[S] * q_max`` (per channel) on the record
            periodogram; ``per-bin``: the per-bin quantiles; ``per-frame``: the
            pooled per-frame quantiles on STFT frames (per bin, not corrected);
            ``frame-family-wise``: ``E_frame * q_frame_max`` per channel, the
            live monitor's per-frame detector (``alpha_meaning="per-frame"``).
        """
        correction: Correction
        if meaning == "family-wise":
            factor = np.array([q.value for q in self.family_wise])
            values, freqs, tested, E = self.expected * factor, self.freqs_hz, self.tested, self.expected
            correction = "none"
        elif meaning == "per-bin":
            values, freqs, tested, E = self.expected * self.per_bin, self.freqs_hz, self.tested, self.expected
            correction = "none"
        elif meaning == "per-frame":
            values = self.frame_expected * self.per_frame
            freqs, tested, E = self.frame_freqs_hz, self.frame_tested, self.frame_expected
            correction = "none"
        elif meaning == "frame-family-wise":
            if not self.frame_family_wise:
                raise CalibrationMismatchError(
                    "this calibration has no per-frame family-wise quantile (made by an older "
                    "chatterspec): recalibrate it"
                )
            factor = np.array([q.value for q in self.frame_family_wise])
            values = self.frame_expected * factor
            freqs, tested, E = self.frame_freqs_hz, self.frame_tested, self.frame_expected
            correction = "none"
        else:
            raise ParameterError(
                f"meaning must be per-bin, family-wise, per-frame or frame-family-wise; got {meaning!r}"
            )
        dof = np.where(tested, 2, 1)
        return Threshold(
            values=_ro(values),
            freqs_hz=_ro(freqs),
            kind="empirical",
            alpha=self.alpha,
            alpha_meaning="per-frame" if meaning == "frame-family-wise" else meaning,
            correction=correction,
            tested=_ro(tested),
            dof=_ro(dof),
            averaged=1,
            per_test_alpha=self.alpha if meaning == "per-bin" else float("nan"),
            expected=_ro(E),
        )

    # ---- the file format (chatterspec.studies.calibration.result)
    def to_dict(self, arrays: bool = False) -> dict[str, Any]:
        """JSON-ready summary; ``arrays=True`` adds every array (the calibration file content).

        See Also
        --------
        chatterspec.studies.calibration.result.calibration_dict : the same as a function.
        """
        return calibration_dict(self, arrays)

    def save(self, path: str | Path) -> Path:
        """Write the calibration file: ``.npz`` (arrays + JSON metadata) or JSON otherwise.

        See Also
        --------
        load_calibration : reads it back.
        """
        return save_calibration(self, path)


def _stft_dict(config: STFTConfig) -> dict[str, Any]:
    return {"window_s": float(config.window_s), "hop_s": float(config.hop_s), "window": str(config.window)}


def load_calibration(
    path: str | Path,
    model: Model | None = None,
    n_samples: int | None = None,
    config: STFTConfig | None = None,
) -> Calibration:
    """Read a calibration file written by :meth:`Calibration.save`.

    With ``model`` (and optionally ``n_samples``, ``config``) the calibration
    is checked against them (:meth:`Calibration.check`).

    Parameters
    ----------
    path : str or Path
        Calibration file: ``.npz`` (arrays plus JSON metadata), otherwise JSON.
    model : LinearModel, optional
        Model the calibration will be used with; its fingerprint must match.
    n_samples : int, optional
        Periodogram record length N (samples) it will be used with.
    config : STFTConfig, optional
        STFT settings (window and hop in seconds, taper) of the per-frame detector.

    Returns
    -------
    Calibration

    Raises
    ------
    DataFileError
        The file is missing or is not a chatterspec calibration.
    CalibrationMismatchError
        It was made for another model, record length or STFT setting.
    """
    cal = Calibration(**read_calibration(path))
    if model is not None:
        cal.check(model, n_samples, config)
    return cal


CALIBRATION_FORMAT = "chatterspec-calibration"
CALIBRATION_VERSION = 1


def calibration_dict(cal: Calibration, arrays: bool = False) -> dict[str, Any]:
    """``cal`` as a JSON-ready dict (what ``Calibration.to_dict`` returns).

    Parameters
    ----------
    cal : Calibration
        The calibration.
    arrays : bool
        Add every array under ``"arrays"`` (non-finite values as ``null``): the JSON file content.

    Returns
    -------
    dict
        Format and version, what was calibrated, the empirical factors, the tails and the alarm rule;
        for an analytic normalization also the analytic factors and :meth:`Calibration.agreement`,
        for an empirical one the normalization and how it was estimated.
    """
    head = {"format": CALIBRATION_FORMAT, "version": CALIBRATION_VERSION}
    what = {k: getattr(cal, k) for k in ("scenario", "model_name", "model_fingerprint", "dt", "n_samples")}
    what |= {k: getattr(cal, k) for k in ("stft", "alpha", "runs", "seed", "confidence")}
    what["channels"] = list(cal.channels)
    empirical = {
        "per_bin_factor_median": [float(v) for v in np.median(cal.per_bin[cal.tested], axis=0)],
        "per_frame_factor_median": [float(v) for v in np.median(cal.per_frame[cal.frame_tested], axis=0)],
        "family_wise": [q.to_dict() for q in cal.family_wise],
        "frame_family_wise": [q.to_dict() for q in cal.frame_family_wise],
    }
    tail = {"tails": cal.tails, "alarm": None if cal.alarm is None else cal.alarm.to_dict()}
    if cal.source:  # recorded healthy data (a simulated calibration's document is unchanged)
        tail["source"] = dict(cal.source)
    if cal.normalization == "empirical":
        norm = {"normalization": cal.normalization, "normalization_info": cal.normalization_info}
        d: dict[str, Any] = {**head, **norm, **what, "empirical": empirical, **tail}
    else:
        t = cal.tested
        analytic_factor = {
            "exact_per_bin": float(np.median(cal.exact_factor[t])),
            "family_wise_bonferroni": cal.family_wise_analytic["bonferroni"],
            "family_wise_sidak": cal.family_wise_analytic["sidak"],
            "paper_over_expected_min_max": [
                float(np.min(cal.analytic["paper"][t] / cal.expected[t])),
                float(np.max(cal.analytic["paper"][t] / cal.expected[t])),
            ],
        }
        d = {**head, **what, "analytic_factor": analytic_factor, "empirical": empirical}
        d |= {"agreement": cal.agreement(), **tail}
    if arrays:
        d["arrays"] = _json_arrays(cal)
    return d


def _arrays(cal: Calibration) -> dict[str, np.ndarray]:
    """The arrays of a calibration file, by file key."""
    a = {
        "freqs_hz": cal.freqs_hz,
        "tested": cal.tested.astype(np.int8),
        "expected": cal.expected,
        "per_bin": cal.per_bin,
        "per_bin_low": cal.per_bin_low,
        "per_bin_high": cal.per_bin_high,
        "frame_freqs_hz": cal.frame_freqs_hz,
        "frame_tested": cal.frame_tested.astype(np.int8),
        "frame_expected": cal.frame_expected,
        "per_frame": cal.per_frame,
        "per_frame_low": cal.per_frame_low,
        "per_frame_high": cal.per_frame_high,
    }
    a.update({f"analytic:{k}": v for k, v in cal.analytic.items()})
    a.update({f"frame_analytic:{k}": v for k, v in cal.frame_analytic.items()})
    return a


def _json_arrays(cal: Calibration) -> dict[str, list]:
    """:func:`_arrays` as JSON lists, non-finite values as ``null`` (read back by :func:`_json_array`)."""
    return {k: np.where(np.isfinite(v), v, None).tolist() for k, v in _arrays(cal).items()}  # type: ignore[call-overload]  # numpy's stubs: no None in where (an object array)


def save_calibration(cal: Calibration, path: str | Path) -> Path:
    """Write ``cal`` to ``path``: ``.npz`` (arrays + JSON metadata) or JSON otherwise.

    Parameters
    ----------
    cal : Calibration
        The calibration.
    path : str or Path
        The file; its suffix chooses the format.

    Returns
    -------
    Path
        ``path``.

    See Also
    --------
    load_calibration : reads it back.
    """
    path = Path(path)
    meta = calibration_dict(cal, arrays=False)
    meta.pop("agreement", None)
    meta["family_wise"] = [q.to_dict() for q in cal.family_wise]
    meta["frame_family_wise"] = [q.to_dict() for q in cal.frame_family_wise]
    meta["family_wise_analytic"] = cal.family_wise_analytic
    meta["normalization"] = cal.normalization
    meta["normalization_info"] = cal.normalization_info
    meta["tails"] = cal.tails
    if path.suffix == ".npz":
        arrays: dict[str, Any] = {
            "_meta": np.array(json.dumps(meta)),
            **_arrays(cal),
        }  # (savez's keywords: any arrays)
        np.savez(path, **arrays)
    else:
        meta["arrays"] = _json_arrays(cal)
        path.write_text(json.dumps(meta))
    return path


def _json_array(key: str, value: object) -> np.ndarray:
    a = np.asarray(value, dtype=object)
    sign = -1.0 if key.endswith("_low") else 1.0
    return np.where(a == None, sign * np.inf, a).astype(float)  # noqa: E711


def read_calibration(path: str | Path) -> dict[str, Any]:
    """The fields of the :class:`~chatterspec.studies.calibration.result.Calibration` in file ``path``.

    Parameters
    ----------
    path : str or Path
        Calibration file written by :func:`save_calibration`: ``.npz`` (arrays plus JSON metadata),
        otherwise JSON.

    Returns
    -------
    dict
        ``Calibration(**fields)`` is the calibration (read-only arrays).

    Raises
    ------
    DataFileError
        The file is missing, incomplete (the message names what it lacks) or not a chatterspec
        calibration.

    See Also
    --------
    chatterspec.studies.calibration.result.load_calibration : the calibration itself, checked against a model.
    """
    path = Path(path)
    try:
        return _read_fields(path)
    except KeyError as exc:  # an incomplete file: name what is missing in words, not KeyError: 'arrays'
        key = str(exc.args[0]) if exc.args else "?"
        what = _CALIBRATION_KEY_WORDS.get(key, f"the entry {key!r}")
        raise DataFileError(
            f"{path}: incomplete calibration file: it has no {what}; write it again with "
            "'chatterspec calibrate NAME --out FILE'"
        ) from None


#: Words for the entries of a calibration file (messages of :func:`read_calibration`).
_CALIBRATION_KEY_WORDS = {
    "arrays": "threshold arrays ('arrays')",
    "_meta": "metadata ('_meta')",
    "confidence": "confidence level ('confidence')",
    "scenario": "scenario name ('scenario')",
    "model_fingerprint": "model fingerprint ('model_fingerprint')",
    "n_samples": "record length ('n_samples')",
    "stft": "STFT settings ('stft')",
    "alpha": "alpha ('alpha')",
    "per_bin": "per-bin quantiles ('per_bin')",
    "per_frame": "per-frame quantiles ('per_frame')",
    "family_wise_analytic": "analytic family-wise factors ('family_wise_analytic')",
}


def _read_fields(path: Path) -> dict[str, Any]:
    try:
        if path.suffix == ".npz":
            with np.load(path, allow_pickle=False) as z:
                if "_meta" not in z.files:  # e.g. a data file: say what it is, not a KeyError's text
                    held = ", ".join(sorted(z.files)[:6]) + (", ..." if len(z.files) > 6 else "")
                    raise DataFileError(
                        f"{path}: not a chatterspec calibration file: the .npz archive holds "
                        f"[{held or 'nothing'}] but no calibration metadata ('_meta'); write one with "
                        "'chatterspec calibrate NAME --out FILE'"
                    )
                meta = json.loads(str(z["_meta"]))
                arrays = {k: np.array(z[k]) for k in z.files if k != "_meta"}
        else:
            meta = json.loads(path.read_text())
            if not isinstance(meta, dict) or meta.get("format") != CALIBRATION_FORMAT:
                fmt = meta.get("format") if isinstance(meta, dict) else None
                raise DataFileError(f"{path}: not a chatterspec calibration file (format {fmt!r})")
            arrays = {k: _json_array(k, v) for k, v in meta.pop("arrays").items()}
    except KeyError:
        raise
    except (OSError, ValueError, TypeError, EOFError, zipfile.BadZipFile) as exc:
        if isinstance(exc, DataFileError):
            raise
        if isinstance(exc, json.JSONDecodeError):
            raise DataFileError(
                f"{path}: not a chatterspec calibration file (neither an .npz archive nor JSON; write one "
                "with 'chatterspec calibrate NAME --out FILE')"
            ) from None
        reason = "not a zip of .npy arrays" if "pickle" in str(exc) else f"{type(exc).__name__}: {exc}"
        raise DataFileError(f"{path}: cannot read calibration file ({reason})") from None
    if meta.get("format") != CALIBRATION_FORMAT:
        raise DataFileError(f"{path}: not a chatterspec calibration file (format {meta.get('format')!r})")
    if meta.get("version") != CALIBRATION_VERSION:
        raise DataFileError(f"{path}: calibration file version {meta.get('version')} is not supported")
    conf = float(meta["confidence"])

    def quantiles(key: str) -> tuple[QuantileEstimate, ...]:
        return tuple(
            QuantileEstimate(
                q["q"], q["value"], _none_to_inf(q["ci_low"], -1), _none_to_inf(q["ci_high"], 1), q["n"], conf
            )
            for q in meta.get(key, ())
        )

    fw = quantiles("family_wise")
    return dict(
        scenario=meta["scenario"],
        model_name=meta["model_name"],
        model_fingerprint=meta["model_fingerprint"],
        dt=float(meta["dt"]),
        n_samples=int(meta["n_samples"]),
        stft=dict(meta["stft"]),
        alpha=float(meta["alpha"]),
        runs=int(meta["runs"]),
        seed=meta["seed"],
        confidence=conf,
        channels=tuple(meta["channels"]),
        freqs_hz=_ro(arrays["freqs_hz"].astype(float)),
        tested=_ro(arrays["tested"].astype(bool)),
        expected=_ro(arrays["expected"].astype(float)),
        analytic={
            k.split(":", 1)[1]: _ro(v.astype(float)) for k, v in arrays.items() if k.startswith("analytic:")
        },
        per_bin=_ro(arrays["per_bin"].astype(float)),
        per_bin_low=_ro(arrays["per_bin_low"].astype(float)),
        per_bin_high=_ro(arrays["per_bin_high"].astype(float)),
        family_wise=fw,
        family_wise_analytic={k: float(v) for k, v in meta["family_wise_analytic"].items()},
        frame_freqs_hz=_ro(arrays["frame_freqs_hz"].astype(float)),
        frame_tested=_ro(arrays["frame_tested"].astype(bool)),
        frame_expected=_ro(arrays["frame_expected"].astype(float)),
        frame_analytic={
            k.split(":", 1)[1]: _ro(v.astype(float))
            for k, v in arrays.items()
            if k.startswith("frame_analytic:")
        },
        per_frame=_ro(arrays["per_frame"].astype(float)),
        per_frame_low=_ro(arrays["per_frame_low"].astype(float)),
        per_frame_high=_ro(arrays["per_frame_high"].astype(float)),
        frame_family_wise=quantiles("frame_family_wise"),
        normalization=str(meta.get("normalization", "analytic")),
        normalization_info=dict(meta.get("normalization_info", {})),
        tails=dict(meta.get("tails", {})),
        alarm=None if meta.get("alarm") is None else RuleCalibration.from_dict(meta["alarm"]),
        source=dict(meta.get("source", {})),
    )


def _ro(a: np.ndarray) -> np.ndarray:
    return readonly(np.array(a))  # a copy: the caller's arrays stay writable


def _interval_fields(name: str, q: Sequence[np.ndarray]) -> dict[str, Any]:
    """``name``, ``name_low``, ``name_high`` of a :class:`Calibration` from the triple ``q`` (copies)."""
    return {name: _ro(q[0]), f"{name}_low": _ro(q[1]), f"{name}_high": _ro(q[2])}
