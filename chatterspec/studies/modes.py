"""Mode-identification outputs of the multiple-model filters.

* :func:`confusion_matrix`: the IMM paper's Tables 5-7 -- cell ``[i, a]`` is the mean probability of
  mode ``i`` over the samples whose actual mode is ``a``, in percent; every column sums to 100.
* :func:`argmax_accuracy`: fraction of the samples of each actual mode whose most probable mode is the
  actual one.
* :func:`switch_delays`: time for the true mode's probability to pass given levels (0.5, 0.8) after
  each mode switch, per run and for the run-mean probability (the SMM paper's Fig 5 reads the mean).
* :func:`rmse_table`: RMSE per state for several estimators (the SMM paper's SVSF vs SMM-SVSF table).

All functions take the probabilities as ``(runs, T, r)`` (``MultipleModelOutput.mu``) and the true
mode per sample as ``(T,)`` or ``(runs, T)`` integer indices (-1 = no mode, ignored), e.g.
``scenario.filter_settings.mode_index(scenario)``.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from .._validate import finite_array
from ..errors import ParameterError, ShapeError

__all__ = [
    "ModeReport",
    "SwitchDelays",
    "argmax_accuracy",
    "confusion_matrix",
    "mode_report",
    "rmse_table",
    "switch_delays",
]


def _inputs(mu: npt.ArrayLike, true_mode: npt.ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    mu = finite_array("mu", mu, ndim=(2, 3))
    if mu.ndim == 2:
        mu = mu[None]
    runs, T, r = mu.shape
    tm = np.asarray(true_mode)
    if not np.issubdtype(tm.dtype, np.integer):
        raise ParameterError(f"true_mode must hold integer mode indices; got dtype {tm.dtype}")
    if tm.shape == (T,):
        tm = np.broadcast_to(tm, (runs, T))
    if tm.shape != (runs, T):
        raise ShapeError(f"true_mode must have shape ({T},) or ({runs}, {T}) like mu; got {tm.shape}")
    if np.any(tm >= r) or np.any(tm < -1):
        raise ParameterError(f"true_mode entries must lie in -1 .. {r - 1} (-1 = no mode)")
    return mu, tm


def confusion_matrix(mu: np.ndarray, true_mode: np.ndarray) -> np.ndarray:
    """Mean mode probability per actual mode, in percent (IMM paper Tables 5-7).

    Parameters
    ----------
    mu : (runs, T, r) array
        Mode probabilities per sample.
    true_mode : (T,) or (runs, T) int array
        Actual mode index per sample (-1: ignored).

    Returns
    -------
    (r, r) ndarray
        ``C[i, a]`` = mean of ``mu[..., i]`` over the samples of actual mode ``a``, x 100; rows =
        predicted, columns = actual; every column sums to 100 (NaN for a mode that never occurs).
    """
    mu, tm = _inputs(mu, true_mode)
    r = mu.shape[-1]
    out = np.full((r, r), np.nan)
    for a in range(r):
        sel = tm == a
        if sel.any():
            out[:, a] = 100.0 * mu[sel].mean(axis=0)
    return out


def argmax_accuracy(mu: np.ndarray, true_mode: np.ndarray) -> np.ndarray:
    """Fraction of the samples of each actual mode whose most probable mode is that mode.

    Parameters
    ----------
    mu : (runs, T, r) array
        Mode probabilities per sample.
    true_mode : (T,) or (runs, T) int array
        Actual mode index per sample (-1: ignored).

    Returns
    -------
    (r,) ndarray
        In [0, 1]; NaN for a mode that never occurs.
    """
    mu, tm = _inputs(mu, true_mode)
    r = mu.shape[-1]
    hit = np.argmax(mu, axis=-1) == tm
    return np.array([hit[tm == a].mean() if np.any(tm == a) else np.nan for a in range(r)])


@dataclass(frozen=True, eq=False)
class SwitchDelays:
    """Time for the new mode's probability to pass given levels after each switch.

    Attributes
    ----------
    onsets : (s,) array
        Switch times in seconds (first sample of the new mode).
    new_modes : (s,) int array
        Index of the mode switched to.
    levels : (L,) array
        Probability levels (e.g. 0.5, 0.8).
    per_run : (runs, s, L) array
        Delay in seconds per run (NaN: never passed before the next switch or the end).
    of_mean : (s, L) array
        Delay of the run-mean probability (NaN: never passed).
    """

    onsets: np.ndarray
    new_modes: np.ndarray
    levels: np.ndarray
    per_run: np.ndarray
    of_mean: np.ndarray


def _first_crossing(p: np.ndarray, level: float) -> np.ndarray:
    """Index of the first sample with ``p >= level`` along the last axis (-1 if none)."""
    hit = p >= level
    idx = np.argmax(hit, axis=-1)
    return np.where(hit.any(axis=-1), idx, -1)


def switch_delays(
    mu: np.ndarray, true_mode: np.ndarray, t: np.ndarray, levels: Sequence[float] = (0.5, 0.8)
) -> SwitchDelays:
    """Delays from each mode switch until the new mode's probability passes each level.

    A switch is a sample where the (shared) true mode changes to another valid mode. The search
    runs until the next switch or the end of the record.

    Parameters
    ----------
    mu : (runs, T, r) array
        Mode probabilities per sample.
    true_mode : (T,) int array
        Actual mode per sample, shared by all runs.
    t : (T,) array
        Sample times in seconds (same samples as ``mu``).
    levels : sequence of float
        Probability levels in (0, 1].

    Returns
    -------
    SwitchDelays
    """
    mu, tm = _inputs(mu, true_mode)
    tm1 = tm[0]
    if np.any(tm != tm1):
        raise ParameterError("switch_delays needs one true-mode sequence shared by all runs")
    t = finite_array("t", t, shape=(mu.shape[1],))
    lev = finite_array("levels", levels, ndim=1)
    if np.any((lev <= 0) | (lev > 1)):
        raise ParameterError(f"levels must lie in (0, 1]; got {lev.tolist()}")
    change = np.flatnonzero((tm1[1:] != tm1[:-1]) & (tm1[1:] >= 0)) + 1
    ends = np.append(change[1:], len(tm1))
    runs = mu.shape[0]
    per_run = np.full((runs, len(change), len(lev)), np.nan)
    of_mean = np.full((len(change), len(lev)), np.nan)
    for s, (k0, k1) in enumerate(zip(change, ends, strict=True)):
        p = mu[:, k0:k1, tm1[k0]]
        pm = p.mean(axis=0)
        for li, level in enumerate(lev):
            idx = _first_crossing(p, level)
            per_run[:, s, li] = np.where(idx >= 0, t[k0 + np.maximum(idx, 0)] - t[k0], np.nan)
            im = int(_first_crossing(pm, level))
            if im >= 0:
                of_mean[s, li] = t[k0 + im] - t[k0]
    return SwitchDelays(t[change], tm1[change], lev, per_run, of_mean)


def rmse_table(
    estimates: Mapping[str, np.ndarray], truth: np.ndarray, state_names: Sequence[str] | None = None
) -> dict[str, dict[str, float]]:
    """RMSE per state over all runs and samples, for each estimator (the SMM paper's RMSE table).

    Parameters
    ----------
    estimates : mapping of str to (runs, T, n) array
        Estimator name -> estimates aligned with ``truth``.
    truth : (runs, T, n) array
        True states.
    state_names : sequence of str, optional
        Names of the n states (default ``x1 .. xn``).

    Returns
    -------
    dict
        ``{estimator: {state: rmse}}`` in the states' units.
    """
    truth = finite_array("truth", truth, ndim=3)
    n = truth.shape[-1]
    names = tuple(state_names) if state_names is not None else tuple(f"x{i + 1}" for i in range(n))
    if len(names) != n:
        raise ShapeError(f"state_names must name the {n} states; got {len(names)}")
    table: dict[str, dict[str, float]] = {}
    for key, est in estimates.items():
        est = finite_array(f"estimates[{key!r}]", est, shape=truth.shape)
        rm = np.sqrt(np.mean((est - truth) ** 2, axis=(0, 1)))
        table[str(key)] = {nm: float(v) for nm, v in zip(names, rm, strict=True)}
    return table


@dataclass(frozen=True, eq=False)
class ModeReport:
    """Confusion matrix, argmax accuracy and switch delays of one multiple-model run.

    Attributes
    ----------
    modes : tuple of str
        Mode names.
    confusion : (r, r) array
        :func:`confusion_matrix` (percent; rows predicted, columns actual).
    accuracy : (r,) array
        :func:`argmax_accuracy`.
    delays : SwitchDelays
        :func:`switch_delays` at levels 0.5 and 0.8.
    """

    modes: tuple[str, ...]
    confusion: np.ndarray
    accuracy: np.ndarray
    delays: SwitchDelays

    def describe(self) -> dict[str, object]:
        """JSON-ready summary (NaN -> None)."""

        def clean(a: np.ndarray) -> object:
            return np.where(np.isnan(a), None, np.round(a, 10)).tolist()  # type: ignore[call-overload]  # numpy's stubs: no None in where (an object array)

        return {
            "modes": list(self.modes),
            "confusion_percent": clean(self.confusion),
            "argmax_accuracy": clean(self.accuracy),
            "switch_onsets_s": self.delays.onsets.tolist(),
            "switch_to": [self.modes[i] for i in self.delays.new_modes],
            "levels": self.delays.levels.tolist(),
            "delay_of_mean_s": clean(self.delays.of_mean),
            "delay_median_s": clean(np.nanmedian(self.delays.per_run, axis=0))
            if self.delays.per_run.size and not np.all(np.isnan(self.delays.per_run))
            else None,
        }


def mode_report(
    mu: np.ndarray,
    true_mode: np.ndarray,
    t: np.ndarray,
    modes: Sequence[str],
    levels: Sequence[float] = (0.5, 0.8),
) -> ModeReport:
    """All mode outputs at once.

    Parameters
    ----------
    mu : (runs, T, r) array
        Mode probabilities per sample.
    true_mode : (T,) int array
        Actual mode per sample.
    t : (T,) array
        Sample times in seconds.
    modes : sequence of str
        Mode names (r of them).
    levels : sequence of float
        Levels of :func:`switch_delays`.

    Returns
    -------
    ModeReport
    """
    names = tuple(str(s) for s in modes)
    if len(names) != np.shape(mu)[-1]:
        raise ShapeError(f"modes must name the {np.shape(mu)[-1]} modes; got {len(names)}")
    return ModeReport(
        names,
        confusion_matrix(mu, true_mode),
        argmax_accuracy(mu, true_mode),
        switch_delays(mu, true_mode, t, levels),
    )
