"""The calibration file format: a :class:`~chatterspec.studies.calibration_result.Calibration` as JSON
or as ``.npz`` arrays with a JSON header.

:meth:`Calibration.to_dict <chatterspec.studies.calibration_result.Calibration.to_dict>` and
:meth:`~chatterspec.studies.calibration_result.Calibration.save` call :func:`calibration_dict` and
:func:`save_calibration`; :func:`read_calibration` reads a file back into the fields that
:func:`~chatterspec.studies.calibration_result.load_calibration` (documented home
:mod:`chatterspec.studies.calibration`) turns into a checked ``Calibration``. Version
:data:`CALIBRATION_VERSION` of format :data:`CALIBRATION_FORMAT`.
"""

from __future__ import annotations

import json
import zipfile
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from .._validate import readonly
from ..detection.alarms.calibration import RuleCalibration
from ..errors import DataFileError
from .intervals import QuantileEstimate, _none_to_inf

if TYPE_CHECKING:
    from .calibration_result import Calibration

__all__ = [
    "CALIBRATION_FORMAT",
    "CALIBRATION_VERSION",
    "calibration_dict",
    "read_calibration",
    "save_calibration",
]

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
    """The fields of the :class:`~chatterspec.studies.calibration_result.Calibration` in file ``path``.

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
    chatterspec.studies.calibration.load_calibration : the calibration itself, checked against a model.
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
