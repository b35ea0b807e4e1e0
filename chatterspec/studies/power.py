"""Detection power vs fault size and noise, and ROC curves."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Unpack, cast

import numpy as np

from .._validate import open_unit, positive_int
from ..detection.pipeline import iter_chattering
from ..detection.spectral import periodogram
from ..errors import ParameterError
from ..montecarlo import Execution, ExecutionOptions, SeedLike, seed_label
from ..plants.models import EHA_PARAMETERS, EHAFault, LinearModel, eha_linear, second_order
from ..plants.scenarios import Scenario
from ..plants.signals import Chirp, Step
from .calibration_result import _ro
from .healthy import _analytic_thresholds, _SummedChunks
from .intervals import RateEstimate

__all__ = [
    "POWER_FAMILIES",
    "PowerResult",
    "power_scenario",
    "power_study",
]

# --------------------------------------------------------------------------- power
#: Fault families of :func:`power_study`: default sizes (first = healthy), noise levels (R multipliers),
#: the fault channel and the unit of the size.
POWER_FAMILIES: dict[str, dict[str, Any]] = {
    "leakage": {
        "sizes": (EHA_PARAMETERS["leakage"], 1e-11, 2e-11, 3e-11, 6e-11, 9e-11),
        "noise": (1.0, 10.0),
        "channel": "pressure",
        "unit": "m^3/(s Pa)",
    },
    "bulk-modulus": {
        "sizes": (1.0, 0.95, 0.9, 0.75, 0.5),
        "noise": (1.0, 10.0),
        "channel": "pressure",
        "unit": "x nominal",
    },
    "friction": {
        "sizes": (EHA_PARAMETERS["friction"], 3000.0, 4000.0, 7000.0),
        "noise": (1.0, 10.0),
        "channel": "velocity",
        "unit": "N s/m",
    },
    "f0": {
        "sizes": (10.0, 10.25, 10.5, 11.0, 12.0),
        "noise": (1.0, 100.0),
        "channel": "velocity",
        "unit": "Hz (true f0, nominal 10 Hz)",
    },
}

_SO_Q = np.diag([1e-8, 1e-6])
_SO_R = np.diag([1e-8, 1e-6])


def power_scenario(family: str, size: float, noise: float = 1.0) -> Scenario:
    """The scenario of one point of a power sweep.

    Parameters
    ----------
    family : {"leakage", "bulk-modulus", "friction", "f0"}
    size : float
        Leakage coefficient, bulk-modulus factor, friction coefficient or true f0 (Hz).
    noise : float
        Multiplier of the measurement noise covariance R (nominal and true plant):
        EHA ``R = noise * diag(1e-6, 1e-6, 1e6)``; second order ``noise * diag(1e-8, 1e-6)``
        (100 = the catalogue's "high" noise).
    """
    if family not in POWER_FAMILIES:
        raise ParameterError(f"unknown fault family {family!r}; valid: {', '.join(POWER_FAMILIES)}")
    size, noise = float(size), float(noise)
    if not (np.isfinite(size) and size > 0 and np.isfinite(noise) and noise > 0):
        raise ParameterError(f"fault size and noise level must be finite and > 0; got {size}, {noise}")
    plant = _true_plant(family, size, noise)
    _check_stable(family, size, plant)
    if family == "f0":
        nominal = second_order(10.0, 0.1, Q=_SO_Q, R=noise * _SO_R)
        inp: Any = Step(0.0)
    else:
        nominal = eha_linear(R=noise * np.diag([1e-6, 1e-6, 1e6]))
        inp = Chirp(10.0, 100.0, 4.0, 300.0)
    return Scenario(
        name=f"power-{family}-{size:g}-noise{noise:g}",
        nominal=nominal,
        plant=plant,
        input=inp,
        duration=4.0,
        family="second-order" if family == "f0" else "eha",
        fault=family,
        fault_channel=POWER_FAMILIES[family]["channel"],
    )


def _true_plant(family: str, size: float, noise: float = 1.0) -> LinearModel:
    """The true (faulty) plant of :func:`power_scenario` (Euler-discretized like the paper's models)."""
    if family == "f0":
        return second_order(size, 0.1, Q=_SO_Q, R=noise * _SO_R)
    key = {"leakage": "leakage", "bulk-modulus": "bulk_modulus", "friction": "friction"}[family]
    value = size * EHA_PARAMETERS["bulk_modulus"] if family == "bulk-modulus" else size
    return eha_linear(R=noise * np.diag([1e-6, 1e-6, 1e6]), **cast(EHAFault, {key: value}))


#: Largest spectral radius of the true plant's discrete A accepted as stable (the EHA position is an
#: integrator: an eigenvalue of exactly 1).
_RHO_MAX = 1.0 + 1e-9


def _spectral_radius(family: str, size: float) -> float:
    return float(np.abs(np.linalg.eigvals(_true_plant(family, size).A)).max())


def _stable_range(family: str) -> tuple[float, float]:
    """``(lo, hi)``: fault sizes around the healthy one with a stable true plant (log-scale bisection)."""
    healthy = float(POWER_FAMILIES[family]["sizes"][0])

    def edge(direction: float) -> float:
        inside, step = healthy, 2.0**direction
        outside = healthy * step
        while _stable(family, outside):  # widen until unstable or implausibly far (then: no edge)
            inside, outside = outside, outside * step
            if not 1e-12 < outside / healthy < 1e12:
                return 0.0 if direction < 0 else np.inf
        for _ in range(60):  # geometric bisection: 2^-60 relative width
            mid = float(np.sqrt(inside * outside))
            inside, outside = (mid, outside) if _stable(family, mid) else (inside, mid)
        return inside

    return edge(-1.0), edge(1.0)


def _stable(family: str, size: float) -> bool:
    try:
        return _spectral_radius(family, size) <= _RHO_MAX
    except ParameterError:
        return False


def _check_stable(family: str, size: float, plant: LinearModel) -> None:
    """A fault size whose true plant is unstable diverges in simulation: reject it up front."""
    rho = float(np.abs(np.linalg.eigvals(plant.A)).max())
    if rho <= _RHO_MAX:
        return
    lo, hi = _stable_range(family)
    unit = POWER_FAMILIES[family]["unit"]
    raise ParameterError(
        f"{family} size {size:g} ({unit}) makes the true plant unstable (discrete A at dt = {plant.dt:g} s "
        f"has spectral radius {rho:.3g} > 1; the simulation would diverge); the stable range is "
        f"{lo:.3g} < size < {hi:.3g} ({unit})"
    )


@dataclass(frozen=True, eq=False)
class PowerStudyChunks(_SummedChunks):
    """Chunk function of :func:`power_study`: detection counts per (point, kind, alpha, channel)."""

    scenarios: tuple[Scenario, ...]
    thr_values: tuple[np.ndarray, ...]  # per point: (K, A, bins, m)
    thr_tested: np.ndarray  # (K, bins)

    def run_chunk(self, first_run: int, runs: int, seed: np.random.SeedSequence) -> dict[str, np.ndarray]:
        """The summary of realizations ``first_run .. first_run + runs - 1`` (a Monte Carlo chunk)."""
        det, det_any = [], []
        for sc, thr in zip(self.scenarios, self.thr_values, strict=True):
            rec = next(iter_chattering(sc, runs, seed, chunk_runs=runs, first_run=first_run))
            S = periodogram(rec.values, rec.dt).power  # (r, bins, m)
            d = np.empty((thr.shape[0], thr.shape[1], runs, S.shape[-1]), dtype=bool)
            for k in range(thr.shape[0]):
                St = S[:, self.thr_tested[k]]  # (r, bt, m)
                d[k] = (St[None] > thr[k][:, None, self.thr_tested[k]]).any(axis=2)  # (A, r, m)
            det.append(d.sum(axis=2))
            det_any.append(d.any(axis=-1).sum(axis=2))
        return {"det": np.stack(det), "det_any": np.stack(det_any)}


@dataclass(frozen=True, eq=False)
class PowerResult:
    """Detection probability per (noise, size, kind, alpha), with Clopper-Pearson intervals.

    Attributes
    ----------
    family : str
    sizes, noise : tuple of float
        Grid (``sizes[0]`` is the healthy value: its "detection" rate is the false-alarm rate).
    kinds : tuple of str
        ``paper`` (per-bin alpha, the paper's rule), ``exact`` (per-bin), ``exact-bonferroni`` (default).
    alphas : (A,) array
        Alpha grid of the ROC; ``alpha`` is the reporting level.
    runs : int
        Realizations per (noise, size) grid point (common random numbers).
    seed : int or None
        Root seed if it was an integer, else None.
    confidence : float
        Level of the Clopper-Pearson intervals.
    channel : str
        Fault channel used for the verdict.
    channels : tuple of str
        All output channel names (last axis of ``counts``).
    counts : (noise, sizes, kinds, A, m) int array
        Records detected (any tested bin above the threshold) per channel.
    counts_any : (noise, sizes, kinds, A) int array
        Records detected on any channel.
    """

    family: str
    sizes: tuple[float, ...]
    noise: tuple[float, ...]
    kinds: tuple[str, ...]
    alphas: np.ndarray
    alpha: float
    runs: int
    seed: int | None
    confidence: float
    channel: str
    channels: tuple[str, ...]
    counts: np.ndarray
    counts_any: np.ndarray

    def _ia(self, alpha: float | None) -> int:
        a = self.alpha if alpha is None else alpha
        return int(np.argmin(np.abs(np.log(self.alphas) - np.log(a))))

    def detection(self, kind: str = "exact-bonferroni", alpha: float | None = None) -> np.ndarray:
        """(noise, sizes) detection probability on the fault channel."""
        c = self.channels.index(self.channel)
        return self.counts[:, :, self.kinds.index(kind), self._ia(alpha), c] / self.runs

    def estimate(self, i_noise: int, i_size: int, kind: str, alpha: float | None = None) -> RateEstimate:
        """Detection rate at noise level ``i_noise``, fault size ``i_size``, threshold ``kind``, ``alpha``."""
        c = self.channels.index(self.channel)
        k = int(self.counts[i_noise, i_size, self.kinds.index(kind), self._ia(alpha), c])
        return RateEstimate(k, self.runs, self.confidence)

    def roc(self, i_noise: int, i_size: int, kind: str = "exact-bonferroni") -> tuple[np.ndarray, np.ndarray]:
        """``(false_alarm_rate, detection_rate)`` over the alpha grid (healthy = ``sizes[0]``)."""
        c = self.channels.index(self.channel)
        k = self.kinds.index(kind)
        far = self.counts[i_noise, 0, k, :, c] / self.runs
        det = self.counts[i_noise, i_size, k, :, c] / self.runs
        return far, det

    def to_dict(self) -> dict[str, Any]:
        """The fields as a JSON-ready dict (what the JSON outputs print)."""
        points = []
        for i, nz in enumerate(self.noise):
            for j, sz in enumerate(self.sizes):
                points.append(
                    {
                        "noise": nz,
                        "size": sz,
                        "healthy": j == 0,
                        "detection": {k: self.estimate(i, j, k).to_dict() for k in self.kinds},
                    }
                )
        roc = []
        for i, nz in enumerate(self.noise):
            for j, sz in enumerate(self.sizes[1:], start=1):
                far, det = self.roc(i, j)
                roc.append(
                    {
                        "noise": nz,
                        "size": sz,
                        "false_alarm_rate": far.tolist(),
                        "detection_rate": det.tolist(),
                    }
                )
        return {
            "family": self.family,
            "unit": POWER_FAMILIES[self.family]["unit"],
            "channel": self.channel,
            "alpha": self.alpha,
            "runs": self.runs,
            "seed": self.seed,
            "confidence": self.confidence,
            "points": points,
            "roc": {"kind": "exact-bonferroni", "alphas": self.alphas.tolist(), "curves": roc},
        }


def power_study(
    family: str,
    sizes: Sequence[float] | None = None,
    noise: Sequence[float] | None = None,
    alpha: float = 1e-3,
    runs: int = 200,
    seed: SeedLike = 0,
    *,
    alphas: Sequence[float] | None = None,
    confidence: float = 0.99,
    **execution: Unpack[ExecutionOptions],
) -> PowerResult:
    """Detection power vs fault size and noise level, and ROC curves.

    Parameters
    ----------
    family : {"leakage", "bulk-modulus", "friction", "f0"}
        Fault family (:data:`POWER_FAMILIES`).
    sizes : sequence of float, optional
        Fault sizes; the family's healthy value is prepended if missing.
    noise : sequence of float, optional
        Measurement-noise multipliers (see :func:`power_scenario`).
    alpha : float
        Reporting level in (0, 1).
    runs : int
        Realizations per grid point (common random numbers across points).
    seed : int
    alphas : sequence of float, optional
        ROC alpha grid (default 1e-5 .. 0.5 log-spaced, plus ``alpha``).
    confidence : float
        Level of the Clopper-Pearson intervals.
    **execution
        ``workers``, ``scheduler``, ``chunk_runs``, ``progress``: how the runs execute
        (:class:`~chatterspec.montecarlo.Execution`).

    Returns
    -------
    PowerResult
    """
    ex = Execution(**execution)
    if family not in POWER_FAMILIES:
        raise ParameterError(f"unknown fault family {family!r}; valid: {', '.join(POWER_FAMILIES)}")
    alpha = open_unit("alpha", alpha)
    runs = positive_int("runs", runs)
    confidence = open_unit("confidence", confidence)
    spec = POWER_FAMILIES[family]
    healthy = spec["sizes"][0]
    sizes_t = tuple(float(s) for s in (spec["sizes"] if sizes is None else sizes))
    if not sizes_t or not math.isclose(sizes_t[0], healthy):
        sizes_t = (healthy, *(s for s in sizes_t if not math.isclose(s, healthy)))
    noise_t = tuple(float(s) for s in (spec["noise"] if noise is None else noise))
    grid = np.geomspace(1e-5, 0.5, 15) if alphas is None else np.asarray(alphas, dtype=float)
    grid = np.unique(np.append([open_unit("alpha", a) for a in grid], alpha))
    kinds = ("paper", "exact", "exact-bonferroni")
    scenarios, thr_values = [], []
    tested = None
    for nz in noise_t:
        for sz in sizes_t:
            sc = power_scenario(family, sz, nz)
            model, N = sc.nominal, sc.n_samples - 1
            per_alpha = [
                _analytic_thresholds(cast(LinearModel, model), N, a)[1] for a in grid
            ]  # linear plants
            thr_values.append(np.stack([np.stack([t[k].values for t in per_alpha]) for k in kinds]))
            tested = np.stack([per_alpha[0][k].tested for k in kinds])
            scenarios.append(sc)
    assert tested is not None  # (one scenario at least)
    study = PowerStudyChunks(tuple(scenarios), tuple(thr_values), tested)
    out = ex.run(study, runs, seed, f"power {family}")
    shape = (len(noise_t), len(sizes_t))
    return PowerResult(
        family=family,
        sizes=sizes_t,
        noise=noise_t,
        kinds=kinds,
        alphas=_ro(grid),
        alpha=alpha,
        runs=runs,
        seed=seed_label(seed),
        confidence=confidence,
        channel=spec["channel"],
        channels=tuple(scenarios[0].nominal.output_names),
        counts=_ro(out["det"].reshape(*shape, *out["det"].shape[1:])),
        counts_any=_ro(out["det_any"].reshape(*shape, *out["det_any"].shape[1:])),
    )
