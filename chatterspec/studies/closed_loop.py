"""Closed-loop studies: the excitation a position loop leaves, and what it does to a fault's footprint.

Excitation study: detection power in closed loop against the reference's richness and a dither.

Under a position controller the actuator moves only as the reference asks. A fault that acts
through the motion -- a leak needs pressure (eq 68 of the core paper: the pressure chattering
carries ``dt be dL / V0 x3``), friction needs velocity (eq 69) -- leaves the chattering at its
noise floor while the actuator holds still. :func:`excitation_study` measures, on the linear EHA
under its catalogue PI controller (:mod:`chatterspec.plants.scenarios`):

* the detection power of one fault (default: the medium leak) on its channel, at the default
  detector's fixed family-wise false-alarm rate (exact threshold, Bonferroni, ``alpha``), and the
  false-alarm rate on the same healthy loop, with Clopper-Pearson intervals;
* against (a) the reference's richness (:data:`EXCITATION_REFERENCES`: held still, one to eight
  S-curve moves, four steps) and (b) a dither on the pump-speed command (a Schroeder multisine or
  a PRBS, amplitude in rad/s), and optionally the position sensor's noise;
* the price: the tracking error (RMS of true position minus reference, mm, per run, averaged
  over runs) and the pump-speed RMS (rad/s).

Every point shares the realizations (common random numbers: the same seed and run indices), so
differences between points are not sampling noise of the noise.

What a position loop does to a fault's footprint: where it hides, where it still shows.

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

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Unpack, cast

import numpy as np

from .._validate import open_unit, positive, positive_int
from ..detection.pipeline import chattering_record
from ..detection.spectral import expected_spectrum, periodogram
from ..errors import ParameterError
from ..montecarlo import Execution, ExecutionOptions, SeedLike, seed_label
from ..plants.closed_loop import PRBS, ClosedLoop, DitherAt, Hold, Multisine, SCurve, StepSequence
from ..plants.models import EHA_PARAMETERS, EHAFault, LinearModel
from ..plants.nonlinear import is_linear
from ..plants.scenarios import (
    EHA_CL_CONTROLLER,
    EHA_CL_POSITION_NOISE,
    EHA_CL_REFERENCE,
    Scenario,
    eha_closed_loop_scenario,
    scenario,
)
from ..plants.signals import Signal
from ..plants.simulate import iter_simulations, simulate
from .calibration.healthy import _analytic_thresholds, _SummedChunks
from .calibration.result import _ro
from .diagnosis import healthy_version
from .intervals import RateEstimate

__all__ = [
    "CLOSED_LOOP_FAMILIES",
    "EXCITATION_REFERENCES",
    "FOOTPRINT_BANDS",
    "ExcitationResult",
    "Footprint",
    "Replay",
    "dither_signal",
    "excitation_points",
    "excitation_scenario",
    "excitation_study",
    "footprint",
    "footprint_table",
    "replayed_open_loop",
    "response_speed_rms",
]

_T4 = (0.25, 1.25, 2.25, 3.25)  # s: move starts of the four-move references

#: The references of the richness axis (m), poorest to richest (4 s records): held still, S-curve moves
#: of growing stroke and number (0.5 s each unless said), steps (which saturate the pump).
EXCITATION_REFERENCES: dict[str, Any] = {
    "hold": Hold(0.0),
    "1-move-2mm": SCurve((0.25,), (0.002,), 0.5),
    "4-moves-1mm": SCurve(_T4, (0.001, -0.001, 0.001, 0.0), 0.5),
    "4-moves-2mm": SCurve(_T4, (0.002, -0.002, 0.002, 0.0), 0.5),
    "1-move": SCurve((0.25,), (0.01,), 0.5),
    "4-moves": EHA_CL_REFERENCE,
    "8-moves": SCurve(
        (0.1, 0.6, 1.1, 1.6, 2.1, 2.6, 3.1, 3.6), (0.01, -0.01, 0.01, -0.01, 0.01, -0.01, 0.01, 0.0), 0.4
    ),
    "4-steps": StepSequence(_T4, (0.01, -0.01, 0.01, 0.0)),
}


def response_speed_rms(reference: str, position_noise: float = EHA_CL_POSITION_NOISE) -> float:
    """The richness measure: RMS velocity (m/s) of the healthy loop's noise-free response to a reference.

    What the reference actually makes the actuator do (a step asks for an infinite speed, the
    saturated pump delivers at most 0.11 m/s); the leak's footprint grows with the pressure, which
    at low frequency follows the velocity (``p = a v / Ac``).

    Parameters
    ----------
    reference : str
        A key of :data:`EXCITATION_REFERENCES`.
    position_noise : float
        Position sensor standard deviation (m) of the loop's nominal model (no effect without noise).
    """
    from ..plants.simulate import loop_response

    _, _, x, _ = loop_response(excitation_scenario("leakage", None, reference, position_noise=position_noise))
    return float(np.sqrt(np.mean(x[:, 1] ** 2)))


#: Fault families of the closed-loop study: the EHA parameter, the default size (Table 2), channel, unit.
CLOSED_LOOP_FAMILIES: dict[str, dict[str, Any]] = {
    "leakage": {"param": "leakage", "size": 6e-11, "channel": "pressure", "unit": "m^3/(s Pa)"},
    "friction": {"param": "friction", "size": 7000.0, "channel": "velocity", "unit": "N s/m"},
    "bulk-modulus": {"param": "bulk_modulus", "size": 0.75, "channel": "pressure", "unit": "x nominal"},
}

#: Tones (Hz) of the default multisine dither: above the loop's 3 Hz bandwidth (the controller does
#: not cancel them) and below the 39 Hz hydraulic mode.
DITHER_TONES_HZ: tuple[float, ...] = (20.0, 30.0, 40.0)


def dither_signal(kind: str, level: float, tones_hz: Sequence[float] = DITHER_TONES_HZ) -> Any:
    """The dither of one study point: ``None`` for level 0, else a multisine or a PRBS.

    Parameters
    ----------
    kind : {"multisine", "prbs"}
        ``multisine``: :class:`~chatterspec.plants.closed_loop.Multisine` of ``level`` rad/s per tone at
        ``tones_hz``; ``prbs``: :class:`~chatterspec.plants.closed_loop.PRBS` of +-``level`` rad/s,
        5 ms clock.
    level : float
        Amplitude in rad/s (>= 0).
    tones_hz : sequence of float
        Multisine tones in Hz.
    """
    if level < 0 or not math.isfinite(level):
        raise ParameterError(f"dither level must be a finite amplitude >= 0 rad/s; got {level!r}")
    if level == 0:
        return None
    if kind == "multisine":
        return Multisine(level, tuple(tones_hz))
    if kind == "prbs":
        return PRBS(level, 0.005)
    raise ParameterError(f"dither signal must be 'multisine' or 'prbs'; got {kind!r}")


def excitation_scenario(
    family: str,
    size: float | None,
    reference: str,
    dither: Signal | None = None,
    *,
    dither_at: DitherAt = "input",
    position_noise: float = EHA_CL_POSITION_NOISE,
) -> Scenario:
    """One point of the study: the linear EHA under the catalogue PI loop, healthy or faulty.

    Parameters
    ----------
    family : {"leakage", "friction", "bulk-modulus"}
        Fault family (:data:`CLOSED_LOOP_FAMILIES`).
    size : float or None
        Fault size (leakage m^3/(s Pa), friction N s/m, bulk modulus as a factor of the nominal);
        ``None``: the healthy loop.
    reference : str
        A key of :data:`EXCITATION_REFERENCES`.
    dither : Signal, optional
        Added to the pump-speed command (rad/s) or to the reference (m), e.g. from :func:`dither_signal`.
    dither_at : {"input", "reference"}
        Where the dither enters (:class:`~chatterspec.plants.closed_loop.ClosedLoop`).
    position_noise : float
        Position sensor standard deviation in m.
    """
    if family not in CLOSED_LOOP_FAMILIES:
        raise ParameterError(
            f"the closed-loop study covers the EHA families {', '.join(CLOSED_LOOP_FAMILIES)}; got {family!r}"
        )
    if reference not in EXCITATION_REFERENCES:
        raise ParameterError(f"unknown reference {reference!r}; valid: {', '.join(EXCITATION_REFERENCES)}")
    spec = CLOSED_LOOP_FAMILIES[family]
    loop = ClosedLoop(EHA_CL_CONTROLLER, EXCITATION_REFERENCES[reference], dither=dither, dither_at=dither_at)
    params: dict[str, float] = {}
    if size is not None:
        value = positive("size", size)
        params[spec["param"]] = value * EHA_PARAMETERS["bulk_modulus"] if family == "bulk-modulus" else value
    return eha_closed_loop_scenario(
        f"excitation-{family}-{reference}",
        loop,
        fault=family if params else "healthy",
        channel=spec["channel"],
        position_noise=position_noise,
        **cast(EHAFault, params),  # (spec["param"]: one of its keys)
    )


@dataclass(frozen=True, eq=False)
class _ExcitationChunks(_SummedChunks):
    """Chunk function of :func:`excitation_study`: per point, detections and tracking sums."""

    scenarios: tuple[tuple[Scenario, Scenario], ...]  # per point: (healthy, faulty)
    thresholds: tuple[np.ndarray, ...]  # per position noise: (bins, m) exact Bonferroni values
    tested: np.ndarray  # (bins,)
    noise_index: tuple[int, ...]  # per point

    def run_chunk(self, first_run: int, runs: int, seed: np.random.SeedSequence) -> dict[str, np.ndarray]:
        n_points = len(self.scenarios)
        m = self.scenarios[0][0].nominal.n_outputs
        det = np.zeros((n_points, 2, m), dtype=np.int64)  # [point, healthy|faulty, channel]
        det_any = np.zeros((n_points, 2), dtype=np.int64)
        track = np.zeros((n_points, 2))  # sum over runs of the per-run RMS tracking error (m)
        track_sq = np.zeros((n_points, 2))
        u_rms = np.zeros((n_points, 2))
        for p, pair in enumerate(self.scenarios):
            thr = self.thresholds[self.noise_index[p]][self.tested]
            for h, sc in enumerate(pair):
                sim = next(iter_simulations(sc, runs, seed, chunk_runs=runs, first_run=first_run))
                rec = chattering_record(sc.nominal, sim.z, sim.u, scenario=sc, first_run=first_run)
                S = periodogram(rec.values, rec.dt).power[:, self.tested]  # (runs, bins, m)
                flags = (S > thr).any(axis=1)  # (runs, m)
                det[p, h] += flags.sum(axis=0)
                det_any[p, h] += flags.any(axis=1).sum()
                loop = sc.closed_loop
                assert loop is not None  # (an excitation scenario is a closed loop)
                r = loop.reference.sample(sim.t)  # the task, without a reference dither
                rms = np.sqrt(np.mean((sim.x[:, :, loop.output] - r) ** 2, axis=1))
                track[p, h] += rms.sum()
                track_sq[p, h] += (rms**2).sum()
                u_rms[p, h] += np.sqrt(np.mean(sim.u[..., 0] ** 2, axis=1)).sum()
        return {"det": det, "det_any": det_any, "track": track, "track_sq": track_sq, "u_rms": u_rms}


@dataclass(frozen=True, eq=False)
class ExcitationResult:
    """Detection power, false alarms and tracking cost per (sensor noise, point = (reference, dither level)).

    Attributes
    ----------
    family, unit, channel : str
        Fault family, unit of its size, and the channel it acts on (the verdict's channel).
    size : float
        Fault size (``unit``).
    points : tuple of (str, float)
        ``(reference, dither level)``: a key of :data:`EXCITATION_REFERENCES` and a dither
        amplitude in rad/s (per tone for a multisine; 0 = none).
    reference_descriptions : dict
        Reference key -> description.
    response_speed : dict
        Reference key -> RMS velocity of the noise-free healthy response, m/s (the richness measure).
    dither_description : str
        The dither signal (kind and tones).
    position_noise : tuple of float
        Position sensor standard deviations (m).
    alpha : float
        Family-wise false-alarm level of the detector (exact threshold, Bonferroni).
    runs : int
        Realizations per point (shared by all points).
    seed : int or None
    confidence : float
        Level of the Clopper-Pearson intervals.
    channels : tuple of str
    detections : (noise, points, 2, m) int array
        Records flagged per channel, healthy (index 0) and faulty (index 1).
    detections_any : (noise, points, 2) int array
        Records flagged on any channel.
    tracking_mm : (noise, points, 2) array
        Mean over runs of the per-run RMS tracking error (true position - reference, the reference
        without a dither added to it), mm.
    tracking_se_mm : (noise, points, 2) array
        Its Monte Carlo standard error, mm.
    u_rms : (noise, points, 2) array
        Mean over runs of the per-run RMS pump speed, rad/s.
    """

    family: str
    unit: str
    channel: str
    size: float
    points: tuple[tuple[str, float], ...]
    reference_descriptions: dict[str, str]
    response_speed: dict[str, float]
    dither_description: str
    position_noise: tuple[float, ...]
    alpha: float
    runs: int
    seed: int | None
    confidence: float
    channels: tuple[str, ...]
    detections: np.ndarray
    detections_any: np.ndarray
    tracking_mm: np.ndarray
    tracking_se_mm: np.ndarray
    u_rms: np.ndarray

    @property
    def references(self) -> tuple[str, ...]:
        """The references of the points, in order of first appearance."""
        return tuple(dict.fromkeys(r for r, _ in self.points))

    def levels(self, reference: str) -> list[int]:
        """Indices of ``reference``'s points, by increasing dither level."""
        idx = [p for p, (r, _) in enumerate(self.points) if r == reference]
        return sorted(idx, key=lambda p: self.points[p][1])

    def detection(self, i_noise: int, p: int) -> RateEstimate:
        """Detection rate of the faulty loop on the fault channel at point ``p``, with its interval."""
        k = int(self.detections[i_noise, p, 1, self.channels.index(self.channel)])
        return RateEstimate(k, self.runs, self.confidence)

    def false_alarm(self, i_noise: int, p: int, any_channel: bool = False) -> RateEstimate:
        """False-alarm rate of the healthy loop at point ``p`` (fault channel, or any channel)."""
        if any_channel:
            k = int(self.detections_any[i_noise, p, 0])
        else:
            k = int(self.detections[i_noise, p, 0, self.channels.index(self.channel)])
        return RateEstimate(k, self.runs, self.confidence)

    def smallest_dither(self, i_noise: int, reference: str, target: float = 0.95) -> int | None:
        """The point of ``reference`` with the smallest dither whose detection rate is >= ``target``."""
        for p in self.levels(reference):
            if self.detection(i_noise, p).rate >= target:
                return p
        return None

    def tracking_cost_mm(self, i_noise: int, p: int) -> float | None:
        """Healthy tracking RMS at point ``p`` minus at the same reference without dither (mm), if run."""
        ref = self.points[p][0]
        zero = [q for q in self.levels(ref) if self.points[q][1] == 0.0]
        if not zero:
            return None
        return float(self.tracking_mm[i_noise, p, 0] - self.tracking_mm[i_noise, zero[0], 0])

    def rows(self) -> list[dict[str, Any]]:
        """One dict per (sensor noise, point): the table and ``to_dict``."""
        out = []
        for i, noise in enumerate(self.position_noise):
            for p, (ref, level) in enumerate(self.points):
                out.append(
                    {
                        "position_noise_mm": noise * 1e3,
                        "reference": ref,
                        "response_speed_rms_mm_s": self.response_speed[ref] * 1e3,
                        "dither": level,
                        "false_alarm": self.false_alarm(i, p).to_dict(),
                        "false_alarm_any_channel": self.false_alarm(i, p, any_channel=True).to_dict(),
                        "detection": self.detection(i, p).to_dict(),
                        "tracking_rms_mm": float(self.tracking_mm[i, p, 0]),
                        "tracking_rms_se_mm": float(self.tracking_se_mm[i, p, 0]),
                        "tracking_cost_mm": self.tracking_cost_mm(i, p),
                        "tracking_rms_faulty_mm": float(self.tracking_mm[i, p, 1]),
                        "u_rms": float(self.u_rms[i, p, 0]),
                    }
                )
        return out

    def answers(self, target: float = 0.95) -> list[dict[str, Any]]:
        """Per (sensor noise, reference): the smallest dither reaching ``target`` and its tracking cost."""
        out = []
        for i, noise in enumerate(self.position_noise):
            for ref in self.references:
                p = self.smallest_dither(i, ref, target)
                ps = self.levels(ref)
                out.append(
                    {
                        "position_noise_mm": noise * 1e3,
                        "reference": ref,
                        "target": target,
                        "dither_tried": any(self.points[q][1] > 0 for q in ps),
                        "detection_without_dither": self.detection(i, ps[0]).to_dict()
                        if self.points[ps[0]][1] == 0.0
                        else None,
                        "dither": None if p is None else self.points[p][1],
                        "detection": None if p is None else self.detection(i, p).to_dict(),
                        "tracking_rms_mm": None if p is None else float(self.tracking_mm[i, p, 0]),
                        "tracking_cost_mm": None if p is None else self.tracking_cost_mm(i, p),
                    }
                )
        return out

    def to_dict(self) -> dict[str, Any]:
        """The fields as a JSON-ready dict (what the JSON outputs print)."""
        return {
            "family": self.family,
            "size": self.size,
            "unit": self.unit,
            "channel": self.channel,
            "alpha": self.alpha,
            "alpha_meaning": "family-wise (exact threshold, Bonferroni)",
            "runs": self.runs,
            "seed": self.seed,
            "confidence": self.confidence,
            "controller": EHA_CL_CONTROLLER.to_dict(),
            "references": dict(self.reference_descriptions),
            "dither_signal": self.dither_description,
            "dither_unit": "rad/s",
            "points": self.rows(),
            "smallest_dither_for_95_percent": self.answers(0.95),
        }


def excitation_points(
    references: Sequence[str] | None = None, dither: Sequence[float] | None = None
) -> tuple[tuple[str, float], ...]:
    """The study's default design: every reference without dither, and the dither levels while holding.

    Parameters
    ----------
    references : sequence of str, optional
        Keys of :data:`EXCITATION_REFERENCES` (default: all). With ``dither`` given as well, every
        reference is crossed with every level.
    dither : sequence of float, optional
        Dither levels in rad/s (default :data:`DEFAULT_DITHER` on ``hold`` only).

    Returns
    -------
    tuple of (str, float)
    """
    if references is not None and dither is not None:
        return tuple((r, float(d)) for r in references for d in dither)
    if dither is not None:
        return tuple(("hold", float(d)) for d in dither)
    refs = tuple(EXCITATION_REFERENCES) if references is None else tuple(references)
    pts = [(r, 0.0) for r in refs]
    if "hold" in refs:
        pts[refs.index("hold") + 1 : refs.index("hold") + 1] = [("hold", d) for d in DEFAULT_DITHER if d > 0]
    return tuple(pts)


#: Default dither levels (rad/s per tone) of the hold sweep.
DEFAULT_DITHER: tuple[float, ...] = (0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 8.0, 10.0, 16.0)


def excitation_study(
    family: str = "leakage",
    size: float | None = None,
    points: Sequence[tuple[str, float]] | None = None,
    *,
    dither_kind: str = "multisine",
    tones_hz: Sequence[float] = DITHER_TONES_HZ,
    dither_at: DitherAt = "input",
    position_noise: Sequence[float] = (EHA_CL_POSITION_NOISE,),
    alpha: float = 1e-3,
    runs: int = 200,
    seed: SeedLike = 0,
    confidence: float = 0.99,
    **execution: Unpack[ExecutionOptions],
) -> ExcitationResult:
    """Detection power and tracking cost of the closed-loop EHA over references and dither levels.

    Parameters
    ----------
    family : {"leakage", "friction", "bulk-modulus"}
        Fault family (:data:`CLOSED_LOOP_FAMILIES`).
    size : float, optional
        Fault size (default: the family's, e.g. the medium leak 6e-11 m^3/(s Pa)).
    points : sequence of (str, float), optional
        ``(reference, dither level in rad/s)`` pairs (default :func:`excitation_points`: every
        reference without dither, and the hold with :data:`DEFAULT_DITHER`).
    dither_kind : {"multisine", "prbs"}
        The dither signal (:func:`dither_signal`), added to the pump-speed command.
    tones_hz : sequence of float
        Multisine tones in Hz.
    dither_at : {"input", "reference"}
        ``input``: the levels are pump-speed amplitudes in rad/s; ``reference``: the dither is added to
        the position reference and the levels are in mm.
    position_noise : sequence of float
        Position sensor standard deviations in m (default: the catalogue's 10 um; eq 66's is 1e-3).
    alpha : float
        Family-wise false-alarm level of the detector in (0, 1).
    runs : int
        Realizations per point (common random numbers across points).
    seed : int
    confidence : float
        Level of the Clopper-Pearson intervals.
    **execution
        ``workers``, ``scheduler``, ``chunk_runs``, ``progress`` (:class:`~chatterspec.montecarlo.Execution`).

    Returns
    -------
    ExcitationResult

    Raises
    ------
    ParameterError
        On an unknown family or reference, a dither level < 0 or whose peak reaches the
        controller's saturation (300 rad/s), a multisine tone at or above the Nyquist frequency,
        or a non-positive sensor noise.
    """
    ex = Execution(**execution)
    if family not in CLOSED_LOOP_FAMILIES:
        raise ParameterError(
            f"the closed-loop study covers the EHA families {', '.join(CLOSED_LOOP_FAMILIES)}; got {family!r}"
        )
    spec = CLOSED_LOOP_FAMILIES[family]
    size = float(spec["size"] if size is None else positive("size", size))
    pts = excitation_points() if points is None else tuple((str(r), float(d)) for r, d in points)
    if not pts:
        raise ParameterError("the study needs at least one (reference, dither level) point")
    noises = tuple(positive("position_noise", x, unit="m") for x in position_noise)
    alpha = open_unit("alpha", alpha)
    runs = positive_int("runs", runs)
    confidence = open_unit("confidence", confidence)
    pairs, noise_index, thresholds = [], [], []
    tested = None
    for i, noise in enumerate(noises):
        for ref, level in pts:
            d = dither_signal(dither_kind, level * (1e-3 if dither_at == "reference" else 1.0), tones_hz)
            healthy = excitation_scenario(family, None, ref, d, dither_at=dither_at, position_noise=noise)
            faulty = excitation_scenario(family, size, ref, d, dither_at=dither_at, position_noise=noise)
            pairs.append((healthy, faulty))
            noise_index.append(i)
        _, thr = _analytic_thresholds(
            cast(LinearModel, healthy.nominal), healthy.n_samples - 1, alpha
        )  # linear EHA
        thresholds.append(thr["exact-bonferroni"].values)
        tested = thr["exact-bonferroni"].tested
    nyquist = 0.5 / pairs[0][0].dt
    if dither_kind == "multisine" and max(tones_hz) >= nyquist:
        raise ParameterError(
            f"multisine tones must lie below the Nyquist frequency {nyquist:g} Hz (dt = "
            f"{pairs[0][0].dt:g} s): sampled, a {max(tones_hz):g} Hz tone is another frequency; got "
            f"{list(tones_hz)}"
        )
    study = _ExcitationChunks(tuple(pairs), tuple(thresholds), np.asarray(tested), tuple(noise_index))
    out = ex.run(study, runs, seed, f"closed-loop power {family}")
    shape = (len(noises), len(pts))
    mean = out["track"] / runs
    var = np.maximum(out["track_sq"] / runs - mean**2, 0.0) / max(runs - 1, 1)
    refs = tuple(dict.fromkeys(r for r, _ in pts))
    d1 = dither_signal(dither_kind, 1.0, tones_hz)
    unit = "mm on the reference" if dither_at == "reference" else "rad/s on the pump-speed command"
    return ExcitationResult(
        family=family,
        unit=spec["unit"],
        channel=spec["channel"],
        size=size,
        points=pts,
        reference_descriptions={r: EXCITATION_REFERENCES[r].describe() for r in refs},
        response_speed={r: response_speed_rms(r) for r in refs},
        dither_description=d1.describe().replace("1 per tone", "LEVEL per tone").replace("+-1,", "+-LEVEL,")
        + f", LEVEL in {unit}",
        position_noise=noises,
        alpha=alpha,
        runs=runs,
        seed=seed_label(seed),
        confidence=confidence,
        channels=tuple(pairs[0][0].nominal.output_names),
        detections=_ro(out["det"].reshape(*shape, *out["det"].shape[1:])),
        detections_any=_ro(out["det_any"].reshape(*shape, 2)),
        tracking_mm=_ro((mean * 1e3).reshape(*shape, 2)),
        tracking_se_mm=_ro((np.sqrt(var) * 1e3).reshape(*shape, 2)),
        u_rms=_ro((out["u_rms"] / runs).reshape(*shape, 2)),
    )


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
