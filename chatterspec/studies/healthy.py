"""Healthy-run scenarios and the streaming summary of a healthy Monte Carlo study."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import cast

import numpy as np

from .. import _jit
from .._validate import open_unit
from ..detection.pipeline import iter_chattering
from ..detection.spectral import STFTConfig, periodogram, periodogram_freqs
from ..detection.spectral import spectrogram as stft_spectrogram
from ..detection.thresholds import Threshold, exact_threshold, frame_threshold, paper_threshold
from ..errors import ParameterError
from ..plants.models import LinearModel
from ..plants.scenarios import Scenario
from ..plants.scenarios import scenario as catalogue_scenario
from ..plants.signals import ZeroInput
from ._exceedance import exceedance_counts
from .tail_histogram import bucket_counts

__all__ = [
    "model_scenario",
    "resolve_scenario",
]


# --------------------------------------------------------------------------- scenarios


def model_scenario(model: LinearModel, duration: float = 4.0, name: str | None = None) -> Scenario:
    """A healthy scenario for a user model: zero input, the model as nominal and true plant.

    The input is zero on every channel: the healthy chattering of a matched
    linear model does not depend on u.

    Parameters
    ----------
    model : LinearModel
        Nominal model, also used as the true plant (no fault windows).
    duration : float
        Record length in seconds (default 4 s, the paper's record).
    name : str, optional
        Scenario name; default ``model.name``, or ``"user-model"`` if that is empty.

    Returns
    -------
    Scenario
        Family ``"user"``, healthy.
    """
    return Scenario(
        name=name or model.name or "user-model",
        nominal=model,
        input=ZeroInput(model.n_inputs),
        duration=duration,
        description="user model, healthy, zero input",
        family="user",
    )


def resolve_scenario(source: str | Scenario | LinearModel | Path, duration: float = 4.0) -> Scenario:
    """A catalogue name, a TOML model file (``.toml``), a Scenario or a LinearModel -> Scenario.

    Parameters
    ----------
    source : str, Scenario, LinearModel or Path
        A :class:`Scenario` is returned unchanged; a :class:`LinearModel` becomes a healthy
        zero-input scenario (:func:`model_scenario`); a path ending in ``.toml`` (read with
        :func:`~chatterspec.plants.modelfile.load_model`, linear or nonlinear) becomes the healthy
        scenario of its ``[simulation]`` table (zero input by default;
        :func:`~chatterspec.plants.modelfile.file_scenario`), named after the file stem;
        any other string is looked up in the scenario catalogue.
    duration : float
        Record length in seconds for model and model-file sources (a model file's
        ``[simulation] duration_s`` wins); ignored for catalogue names and Scenario objects,
        which carry their own duration.

    Returns
    -------
    Scenario

    Raises
    ------
    UnknownScenarioError
        A string that is neither a ``.toml`` path nor a catalogue name.
    """
    if isinstance(source, Scenario):
        return source
    if isinstance(source, LinearModel):
        return model_scenario(source, duration)
    text = str(source)
    if text.endswith(".toml"):
        from ..plants.modelfile import file_scenario, load_model

        return file_scenario(load_model(text), default_duration=duration, name=Path(text).stem)
    return catalogue_scenario(text)


# --------------------------------------------------------------------------- summaries
def _merge_top(a: np.ndarray, b: np.ndarray, k: int) -> np.ndarray:
    both = np.concatenate([a, b], axis=0)
    if both.shape[0] <= k:
        return both
    # copy: the slice of the partitioned 2k rows would keep all of them alive in the accumulator
    return np.partition(both, both.shape[0] - k, axis=0)[both.shape[0] - k :].copy()


def _reduce_dict(
    acc: dict[str, np.ndarray] | None, part: dict[str, np.ndarray], k_top: dict[str, int]
) -> dict[str, np.ndarray]:
    if acc is None:
        return dict(part)
    out: dict[str, np.ndarray] = {}
    for key, val in part.items():
        if key.startswith("top_"):
            out[key] = _merge_top(acc[key], val, k_top[key])
        elif key.startswith("runs_"):
            out[key] = np.concatenate([acc[key], val], axis=0)
        else:
            out[key] = acc[key] + val
    return out


class _SummedChunks:
    """Base of a study whose chunk summaries are dicts of counts and sums, added chunk by chunk."""

    def reduce(self, acc: dict[str, np.ndarray] | None, part: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        """``acc`` with one chunk's summary ``part`` folded in (``acc`` is None for the first chunk)."""
        return _reduce_dict(acc, part, {})


def _keep_top(x: np.ndarray, k: int) -> np.ndarray:
    """The ``k`` largest values along axis 0 (unsorted)."""
    if k <= 0:
        return x[:0]
    if x.shape[0] <= k:
        return x
    return np.partition(x, x.shape[0] - k, axis=0)[x.shape[0] - k :]


@dataclass(frozen=True, eq=False)
class HealthyStudy:
    """Chunk function of calibration and false-alarm studies (picklable; see :mod:`chatterspec.montecarlo`).

    Thresholds are passed as stacked arrays so that workers do not rebuild them.
    Each chunk simulates healthy chattering, takes its periodogram (and STFT
    frames if ``config`` and ``fthr_values`` are set) and counts exceedances.
    Exported as ``FalseAlarmStudy``.

    Attributes
    ----------
    scenario : Scenario
        Healthy scenario to simulate.
    thr_values : (K, bins, m) array
        Power thresholds of the K record-level kinds, in the squared output
        units of the periodogram (e.g. Pa^2 for pressure).
    thr_tested : (K, bins) bool array
        Bins each kind tests (DC and Nyquist excluded).
    expected : (bins, m) array
        Expected healthy periodogram E[S] (eq 56), used to normalize ``S / E[S]``.
    tested : (bins,) bool array
        Bins over which the normalized per-record maximum is taken.
    config : STFTConfig, optional
        STFT settings of the per-frame kinds; None skips the frame statistics.
    fthr_values : (Kf, fbins, m) array, optional
        Per-frame thresholds of the Kf frame kinds.
    fthr_tested : (Kf, fbins) bool array, optional
        Frame bins each frame kind tests.
    fexpected : (fbins, m) array, optional
        Expected healthy frame spectrum; needed only when ``kf_top > 0``.
    k_top : int
        Largest normalized bin powers to keep (for the empirical per-bin
        quantile interval); 0 keeps none.
    kf_top : int
        Largest normalized frame powers to keep (empirical per-frame quantile).
    keep_max : bool
        Keep each record's normalized maximum over ``tested`` bins (for the
        empirical family-wise threshold).
    bin_window, frame_window, frame_max_window : (lo, hi) pairs of arrays, optional
        Bounded-memory alternative to ``k_top`` / ``kf_top`` (used when those are 0):
        per-cell windows of the tail histograms of :mod:`~.tail_histogram` for the
        normalized bin powers ``(bins, m)``, frame powers ``(fbins, m)`` and frame
        maxima ``(m,)``; the summary then holds ``hist_*`` bucket counts.
    """

    scenario: Scenario
    thr_values: np.ndarray  # (K, bins, m)
    thr_tested: np.ndarray  # (K, bins)
    expected: np.ndarray  # (bins, m)
    tested: np.ndarray  # (bins,) bins of the normalized maximum
    config: STFTConfig | None = None
    fthr_values: np.ndarray | None = None  # (Kf, fbins, m)
    fthr_tested: np.ndarray | None = None  # (Kf, fbins)
    fexpected: np.ndarray | None = None  # (fbins, m)
    k_top: int = 0
    kf_top: int = 0
    keep_max: bool = False
    bin_window: tuple[np.ndarray, np.ndarray] | None = None
    frame_window: tuple[np.ndarray, np.ndarray] | None = None
    frame_max_window: tuple[np.ndarray, np.ndarray] | None = None

    def run_chunk(self, first_run: int, runs: int, seed: np.random.SeedSequence) -> dict[str, np.ndarray]:
        """The summary of realizations ``first_run .. first_run + runs - 1`` (a Monte Carlo chunk)."""
        acc = None
        for rec in iter_chattering(self.scenario, runs, seed, chunk_runs=runs, first_run=first_run):
            acc = self.reduce(acc, self._summarize(rec.values, rec.dt))
        assert acc is not None  # (runs >= 1 records)
        return acc

    def _summarize(self, x: np.ndarray, dt: float) -> dict[str, np.ndarray]:
        out: dict[str, np.ndarray] = {"runs": np.array(x.shape[0])}
        S = periodogram(x, dt).power  # (r, bins, m)
        compiled = _jit.enabled()  # one pass of integer counts, the numbers of the numpy lines
        if compiled:
            out["bin_exceed"], n_false = exceedance_counts(S[:, None], self.thr_values, self.thr_tested)
            n_false = n_false[:, :, 0]  # (K, r, m)
        else:
            exc = S[None] > self.thr_values[:, None]  # (K, r, bins, m)
            out["bin_exceed"] = exc.sum(axis=1)
            masked = exc & self.thr_tested[:, None, :, None]
            n_false = masked.sum(axis=2)  # (K, r, m)
        out["false_bins"] = n_false.sum(axis=1)
        out["false_bins_sq"] = (n_false.astype(np.int64) ** 2).sum(axis=1)
        # per-record squares: the false-alarm intervals come from run-level counts (cluster Clopper-Pearson)
        out["false_total_sq"] = (n_false.sum(axis=-1).astype(np.int64) ** 2).sum(axis=1)  # (K,)
        fw = n_false > 0
        out["fw"] = fw.sum(axis=1)  # (K, m)
        out["fw_any"] = fw.any(axis=-1).sum(axis=1)  # (K,)
        if self.keep_max or self.k_top or self.bin_window is not None:
            Y = S / self.expected
        if self.keep_max:
            out["runs_max"] = Y[:, self.tested].max(axis=1)  # (r, m)
        if self.k_top:
            out["top_bin"] = _keep_top(Y, self.k_top)
        elif self.bin_window is not None:
            out["hist_bin"] = bucket_counts(Y, *self.bin_window)
        if self.config is not None and self.fthr_values is not None:
            fthr_tested = self.fthr_tested
            assert fthr_tested is not None  # (set with fthr_values)
            P = stft_spectrogram(x, dt, self.config).power  # (r, F, fb, m)
            out["frames"] = np.array(P.shape[0] * P.shape[1])
            if compiled:
                out["frame_bin_exceed"], f_n = exceedance_counts(P, self.fthr_values, fthr_tested)
                flags = f_n > 0  # (Kf, r, F, m)
                f_false = f_n.sum(axis=2)  # (Kf, r, m) false frame-bins per record
            else:
                fexc = P[None] > self.fthr_values[:, None, None]  # (Kf, r, F, fb, m)
                out["frame_bin_exceed"] = fexc.sum(axis=(1, 2))  # (Kf, fb, m)
                fmasked = fexc & fthr_tested[:, None, None, :, None]
                flags = fmasked.any(axis=3)  # (Kf, r, F, m)
                f_false = fmasked.sum(axis=(2, 3)).astype(np.int64)  # (Kf, r, m) false frame-bins per record
            out["frame_flag"] = flags.sum(axis=(1, 2))  # (Kf, m)
            out["frame_flag_any"] = flags.any(axis=-1).sum(axis=(1, 2))  # (Kf,)
            # per-record sums of squares (overlapping frames of one record are dependent trials)
            out["frame_false_sq"] = (f_false**2).sum(axis=1)  # (Kf, m)
            out["frame_false_total_sq"] = (f_false.sum(axis=-1) ** 2).sum(axis=1)  # (Kf,)
            f_flag = flags.sum(axis=2).astype(np.int64)  # (Kf, r, m) flagged frames per record
            out["frame_flag_sq"] = (f_flag**2).sum(axis=1)  # (Kf, m)
            out["frame_flag_any_sq"] = (flags.any(axis=-1).sum(axis=2).astype(np.int64) ** 2).sum(axis=1)
            if self.kf_top:
                Yf = (P / cast(np.ndarray, self.fexpected)).reshape(-1, *P.shape[-2:])  # (set with kf_top)
                out["top_frame"] = _keep_top(Yf, self.kf_top)
                if self.keep_max:  # per frame: the largest normalized tested bin (frame family-wise)
                    out["top_frame_max"] = _keep_top(Yf[:, fthr_tested[0]].max(axis=1), self.kf_top)
            elif self.frame_window is not None:
                fexp = cast(np.ndarray, self.fexpected)  # (set with the window)
                Yf = (P / fexp).reshape(-1, *P.shape[-2:])
                out["hist_frame"] = bucket_counts(Yf, *self.frame_window)
                if self.keep_max and self.frame_max_window is not None:
                    out["hist_frame_max"] = bucket_counts(
                        Yf[:, fthr_tested[0]].max(axis=1), *self.frame_max_window
                    )
        return out

    def reduce(self, acc: dict[str, np.ndarray] | None, part: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        """``acc`` with one chunk's summary ``part`` folded in (``acc`` is None for the first chunk)."""
        return _reduce_dict(
            acc, part, {"top_bin": self.k_top, "top_frame": self.kf_top, "top_frame_max": self.kf_top}
        )


def _analytic_thresholds(
    model: LinearModel, n_samples: int, alpha: float
) -> tuple[np.ndarray, dict[str, Threshold]]:
    freqs = periodogram_freqs(n_samples, model.dt)
    return freqs, {
        "paper": paper_threshold(model, freqs, alpha),
        "exact": exact_threshold(model, freqs, n_samples, alpha, correction="none"),
        "exact-bonferroni": exact_threshold(model, freqs, n_samples, alpha, correction="bonferroni"),
        "exact-sidak": exact_threshold(model, freqs, n_samples, alpha, correction="sidak"),
    }


def _frame_thresholds(
    model: LinearModel, config: STFTConfig, alpha: float
) -> tuple[np.ndarray, dict[str, Threshold]]:
    freqs = config.freqs_hz(model.dt)
    return freqs, {
        "frame": frame_threshold(model, freqs, config, model.dt, alpha, correction="none"),
        "frame-bonferroni": frame_threshold(model, freqs, config, model.dt, alpha, correction="bonferroni"),
    }


def _check_alphas(alpha: float | Sequence[float]) -> tuple[float, ...]:
    alphas = (cast(float, alpha),) if np.isscalar(alpha) else tuple(cast(Sequence[float], alpha))
    if not alphas:
        raise ParameterError("alpha: give at least one value")
    return tuple(open_unit("alpha", a) for a in alphas)


def _n_frames(n_samples: int, config: STFTConfig, dt: float) -> int:
    W, H = config.n_window(dt), config.n_hop(dt)
    return max(0, (n_samples - W) // H + 1)
