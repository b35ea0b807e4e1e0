"""What a position loop does to a fault's footprint: where it hides, where it still shows.

For each scenario, its faulty and its healthy version run on the same realizations (same seed and
run indices, so the same noise), and the study reports, per output channel:

* the **chattering** view: detection rate of the default detector (exact threshold, Bonferroni,
  family-wise ``alpha``), the frequency of the largest mean excess power ``S - E[S]``, and how the
  mean excess power (as a fraction of the channel's expected healthy power) splits over frequency
  bands (:data:`FOOTPRINT_BANDS`);
* the **operator's** view, fault minus healthy run by run: the RMS change of each measured channel
  (what the plant does differently; in closed loop the position is what the controller holds) and of
  the pump speed (where a controller moves the fault: its integral action supplies the flow a leak
  takes, so the position barely changes while ``u`` does).

Comparing ``eha-leak-medium`` (open loop) with ``eha-cl-leak-medium`` (the same leak under the PI
loop) and ``eha-cl-hold-leak-medium`` (held still) shows what the loop hides and what the chattering
keeps: the filter gets the measured ``u``, so the pressure chattering still carries the leak's
``dt be dL / V0 x3`` term (eq 68) wherever the pressure moves.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from .._validate import open_unit, positive_int
from ..detection.pipeline import chattering_record
from ..detection.spectral import expected_spectrum, periodogram
from ..errors import ParameterError
from ..plants.nonlinear import is_linear
from ..plants.scenarios import Scenario, scenario
from ..plants.simulate import simulate
from .chattering_diagnosis import healthy_version
from .healthy import _analytic_thresholds

__all__ = ["FOOTPRINT_BANDS", "Footprint", "Replay", "footprint", "footprint_table", "replayed_open_loop"]


@dataclass(frozen=True, eq=False)
class Replay:
    """A recorded command replayed as an open-loop input: ``u(t)`` held from the sample at or before ``t``.

    Attributes
    ----------
    dt : float
        Sampling time of the record in s.
    values : (T,) array
        The command (rad/s) at ``0, dt, 2 dt, ...``; held beyond the end.
    label : str
        What was recorded.
    """

    dt: float
    values: np.ndarray
    label: str = "recorded command"

    def sample(self, t: np.ndarray) -> np.ndarray:
        """The values at the given times (s), one row per time."""
        k = np.clip(
            np.floor(np.asarray(t, dtype=float) / self.dt + 1e-9).astype(np.int64), 0, len(self.values) - 1
        )
        return np.asarray(self.values)[k]

    def describe(self) -> str:
        """A short description for reports and recordings."""
        return f"{self.label}, replayed open loop"


def replayed_open_loop(sc: Scenario) -> Scenario:
    """``sc``'s plant driven open loop by its healthy loop's noise-free command (no feedback).

    The same actuator, the same command profile as the controller gives the healthy actuator, but
    nobody corrects the position: what the leak does to the position when integral action does
    not hide it.

    Parameters
    ----------
    sc : Scenario
        A closed-loop scenario (linear).
    """
    import dataclasses

    from ..plants.simulate import loop_response

    if sc.closed_loop is None:
        raise ParameterError(f"{sc.name!r} runs open loop already")
    _, _, _, u = loop_response(healthy_version(sc))
    replay = Replay(sc.dt, u, f"the healthy loop's command of {sc.name}")
    return dataclasses.replace(sc, name=f"{sc.name}-replayed", input=replay)


#: Frequency bands (Hz) of the excess-power split: below the loop's bandwidth, up to the hydraulic
#: mode, around it (39 Hz), and above.
FOOTPRINT_BANDS: tuple[tuple[float, float], ...] = ((0.0, 5.0), (5.0, 25.0), (25.0, 60.0), (60.0, 500.0))


@dataclass(frozen=True, eq=False)
class Footprint:
    """One scenario's footprint, per output channel (see the module docstring).

    Attributes
    ----------
    scenario : str
        Scenario name.
    closed_loop : bool
        Whether a controller drives the plant.
    channels : tuple of str
    units : tuple of str
        Units of the channels.
    runs : int
    alpha : float
    detection : (m,) array
        Fraction of faulty records flagged per channel.
    false_alarm : (m,) array
        Fraction of healthy records flagged per channel (same realizations).
    peak_hz : (m,) array
        Frequency of the largest mean excess power (Hz) over the tested bins.
    band_excess : (bands, m) array
        Mean excess power ``sum (S - E)`` in each band of :data:`FOOTPRINT_BANDS`, divided by the
        channel's total expected power ``sum E`` over the tested bins.
    delta_rms : (m,) array
        RMS over time and runs of the measured channel's change, fault minus healthy (channel units).
    delta_u_rms : float
        RMS over time and runs of the input's change, fault minus healthy (rad/s; 0 in open loop).
    """

    scenario: str
    closed_loop: bool
    channels: tuple[str, ...]
    units: tuple[str, ...]
    runs: int
    alpha: float
    detection: np.ndarray
    false_alarm: np.ndarray
    peak_hz: np.ndarray
    band_excess: np.ndarray
    delta_rms: np.ndarray
    delta_u_rms: float

    def to_dict(self) -> dict[str, Any]:
        """The fields as a JSON-ready dict (what the JSON outputs print)."""
        return {
            "scenario": self.scenario,
            "closed_loop": self.closed_loop,
            "runs": self.runs,
            "alpha": self.alpha,
            "bands_hz": [list(b) for b in FOOTPRINT_BANDS],
            "channels": {
                c: {
                    "unit": self.units[j],
                    "detection": float(self.detection[j]),
                    "false_alarm": float(self.false_alarm[j]),
                    "peak_hz": float(self.peak_hz[j]),
                    "band_excess": self.band_excess[:, j].tolist(),
                    "delta_rms": float(self.delta_rms[j]),
                }
                for j, c in enumerate(self.channels)
            },
            "delta_u_rms": self.delta_u_rms,
        }


def footprint(source: str | Scenario, runs: int = 100, seed: int = 0, alpha: float = 1e-3) -> Footprint:
    """The footprint of one faulty linear scenario against its healthy version on the same noise.

    Parameters
    ----------
    source : str or Scenario
        A faulty scenario with a linear nominal model (open or closed loop).
    runs : int
        Realizations (>= 2 for a meaningful rate).
    seed : int
        Root seed (shared by the faulty and the healthy runs).
    alpha : float
        Family-wise level of the detector (exact threshold, Bonferroni).

    Returns
    -------
    Footprint
    """
    sc = scenario(source) if isinstance(source, str) else source
    if sc.is_healthy:
        raise ParameterError(f"footprint needs a faulty scenario; {sc.name!r} is healthy")
    if not is_linear(sc.nominal):
        raise ParameterError(f"footprint needs a linear nominal model (analytic E[S]); {sc.name!r} has none")
    runs = positive_int("runs", runs)
    alpha = open_unit("alpha", alpha)
    model = sc.nominal
    sims = [simulate(s, runs, seed) for s in (sc, healthy_version(sc))]
    N = sc.n_samples - 1
    freqs, thr = _analytic_thresholds(model, N, alpha)
    th = thr["exact-bonferroni"]
    E = expected_spectrum(model, freqs, N)
    t = th.tested
    flags, S_mean = [], None
    for k, sim in enumerate(sims):
        rec = chattering_record(model, sim.z, sim.u)
        S = periodogram(rec.values, rec.dt).power
        flags.append((S[:, t] > th.values[t]).any(axis=1).mean(axis=0))
        if k == 0:
            S_mean = S.mean(axis=0)
    excess = (S_mean - E)[t]  # (tested bins, m)
    f = freqs[t]
    total = E[t].sum(axis=0)
    bands = np.array([excess[(f >= lo) & (f < hi)].sum(axis=0) / total for lo, hi in FOOTPRINT_BANDS])
    du = sims[0].u - sims[1].u if sims[0].u.ndim == 3 else np.zeros(1)
    return Footprint(
        scenario=sc.name,
        closed_loop=sc.closed_loop is not None,
        channels=tuple(model.output_names),
        units=tuple(model.output_units),
        runs=runs,
        alpha=alpha,
        detection=flags[0],
        false_alarm=flags[1],
        peak_hz=f[np.argmax(excess, axis=0)],
        band_excess=bands,
        delta_rms=np.sqrt(np.mean((sims[0].z - sims[1].z) ** 2, axis=(0, 1))),
        delta_u_rms=float(np.sqrt(np.mean(du**2))),
    )


def footprint_table(
    names: Sequence[str | Scenario] | None = None,
    runs: int = 100,
    seed: int = 0,
    alpha: float = 1e-3,
) -> tuple[list[Footprint], str]:
    """:func:`footprint` of several scenarios and a text table (one line per scenario and channel).

    Parameters
    ----------
    names : sequence of str or Scenario, optional
        Faulty linear scenarios (default: the medium leak open loop with the catalogue chirp, under
        the PI loop, its command replayed open loop (:func:`replayed_open_loop`), and held still).
    runs : int
        Realizations per scenario.
    seed : int
        Root seed.
    alpha : float
        Family-wise level of the detector.

    Returns
    -------
    (list of Footprint, str)
    """
    if names is None:
        names = (
            "eha-leak-medium",
            "eha-cl-leak-medium",
            replayed_open_loop(scenario("eha-cl-leak-medium")),
            "eha-cl-hold-leak-medium",
        )
    fps = [footprint(n, runs, seed, alpha) for n in names]
    head = (
        f"{'scenario':<28} {'channel':<9} {'detect':>6} {'FA':>5} {'peak Hz':>7} "
        + " ".join(f"{f'{lo:g}-{hi:g} Hz':>9}" for lo, hi in FOOTPRINT_BANDS)
        + f" {'fault-healthy RMS':>20} {'u change':>9}"
    )
    lines = [head]
    for fp in fps:
        for j, c in enumerate(fp.channels):
            unit = fp.units[j] or ""
            scale, unit = (1e3, "mm") if unit == "m" else ((1e3, "mm/s") if unit == "m/s" else (1.0, unit))
            name = fp.scenario if j == 0 else ""
            lines.append(
                f"{name:<28} {c:<9} {fp.detection[j]:>6.2f} {fp.false_alarm[j]:>5.2f} {fp.peak_hz[j]:>7.2f} "
                + " ".join(f"{x:>9.4f}" for x in fp.band_excess[:, j])
                + f" {fp.delta_rms[j] * scale:>14.4g} {unit:<5}"
                + (f" {fp.delta_u_rms:>9.3g}" if j == 0 else "")
            )
    return fps, "\n".join(lines)
