"""The monitor's alarm rules at a false-alarm budget: their thresholds and their detection delays.

Two parts: the rule for a budget (:func:`calibrate_alarm`, healthy score streams and thresholds) and
the delay of the calibrated rules at fault onsets (:func:`alarm_delays`, at the end of the module).

The monitor's alarm rule for a false-alarm budget: healthy score streams and thresholds.

A person watching a monitor all day sets a budget in false alarms per hour for the whole monitor
(all channels together). :func:`alarm_settings` turns a rule name and a budget into
:class:`~chatterspec.online.monitor.MonitorSettings` whose ``rule`` has its threshold set, by
:func:`calibrate_alarm`:

* the frame rule with the exact per-bin law (a linear model): from the law, ``h = log(F m / X)``
  (:func:`chatterspec.detection.alarms.calibration.law_frame_rule`; an upper bound on the rate,
  no simulation);
* every other case: on healthy frame-score streams simulated here
  (:func:`healthy_frame_scores`), counted or extrapolated by
  :func:`chatterspec.detection.alarms.calibration.calibrate_rule`.

Healthy streams
    For a linear model with full measurement the healthy chattering of the auxiliary filter is
    exactly the MA(1) process ``e(k) = C w(k-1) + v(k) - C A C^-1 v(k-1)`` (``w ~ N(0, Q)``,
    ``v ~ N(0, R)``; the input cancels, see :func:`chatterspec.detection.spectral.chattering_autocovariance`),
    so it is drawn directly, block by block (10 minutes of data per block, bounded memory), and cut
    into frames on the monitor's global grid by the monitor's own frame engine and score. A
    nonlinear model has no such closed form: its healthy records are simulated from a healthy
    scenario (:func:`chatterspec.detection.pipeline.iter_chattering`), each record one stream.

Cost and caching
    One hour of 3-channel 1 kHz healthy frames takes 0.6-1.5 s of CPU on this project's 2-core
    machine (the frames are cut on up to 4 threads); :func:`in_call_hours` (12 channel-hours: 4 h
    of the EHA) is what the monitor simulates when it is not given a calibration file, so it
    starts in a few seconds. Results are cached in the process (a ``StreamMonitor`` that resets
    after a gap, or ``detect --record`` on several scenarios, pay once) and, for a linear model, on
    disk in the user cache (:mod:`chatterspec._cache`, keyed by everything that sets the threshold:
    :func:`calibrate_alarm`), so the next process on the same model and settings reads it back.
    The hours are bounded (:func:`check_hours`): at least two frames, at most :data:`MAX_SCORES`
    frame scores. The same seed gives the
    same threshold every time. Precision at one false alarm per day (CUSUM, EHA): the threshold
    from 4 h has a standard deviation of 1.6 (the realized rate within a factor of about 2), from
    24 h of 1.1, from 48 h about 0.8: for all-day use make a calibration file once,
    ``chatterspec calibrate MODEL --rule cusum --false-alarms-per-hour X --out F`` (48 h by
    default, under a minute), and pass it to the monitor.

Detection delay of the alarm rules at fault onsets from a healthy steady state.

A fault of the catalogue is turned into *onset scenarios* (:func:`onset_scenarios`): the true
plant is healthy for ``healthy_s`` seconds, then faulty; the input runs relative to the onset.
For the EHA faults (whole-record faults driven by the 4 s chirp, repeated) one scenario per
input phase at the onset (``phases``), since the fault's footprint depends on where the chirp is
(from 218 nats per frame at its 10 Hz start to 7 at its 100 Hz end for the minor leakage); for the
second-order timelines one scenario per fault window, with the window's input (the step of
``so-timeline-step`` lands at the onset).

:func:`alarm_delays` runs every rule on the same realizations through the monitor's frames and
score (batch STFT, :class:`~chatterspec.detection.verdicts.FrameScore` and
:func:`~chatterspec.detection.alarms.run_rule`: the same numbers as the online monitor, whose
frames, score and alarm layer are these functions on the same grid). The **delay** of a run is the
time of the last sample of the frame at which the first alarm starts, on any channel, among the
frames that end at or after the onset and begin before the fault ends, minus the onset time (s):
when the alarm could have been raised. A run without such a start is a miss. Starts before the
onset are false alarms of the healthy stretch (counted).
"""

from __future__ import annotations

import hashlib
import math
import os
import threading
from collections.abc import Callable, Iterator, Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any, cast

import numpy as np

from .. import _jit
from .._validate import positive
from ..detection.alarms.calibration import (
    MonitorSettings,
    RuleCalibration,
    calibrate_rule,
    check_budget,
    law_frame_rule,
)
from ..detection.alarms.rules import AlarmRule, make_rule, rule_spec
from ..detection.alarms.streams import run_rule
from ..detection.spectral import FrameEngine, STFTConfig, frame_columns, spectrum_model
from ..detection.thresholds import Threshold, monitor_threshold
from ..detection.verdicts import FrameScore
from ..errors import CalibrationMismatchError, ParameterError
from ..jsonout import finite_or_none
from ..plants.nonlinear import Model, is_linear

if TYPE_CHECKING:  # pragma: no cover
    from ..detection.alarms.calibration import MonitorSettings
    from ..plants.nonlinear import Model
    from ..plants.scenarios import Scenario

__all__ = [
    "DEFAULT_BUDGET",
    "DEFAULT_RULE",
    "IN_CALL_CHANNEL_HOURS",
    "IN_CALL_HOURS",
    "DelayResult",
    "Shifted",
    "alarm_delays",
    "alarm_settings",
    "calibrate_alarm",
    "check_alarm_calibration",
    "display_alpha",
    "frames_per_hour",
    "healthy_chattering",
    "healthy_frame_scores",
    "in_call_hours",
    "monitor_score",
    "onset_scenarios",
    "score_delays",
]


#: The monitor's default rule and budget (one false alarm per day, all channels together).
DEFAULT_RULE = "cusum"
DEFAULT_BUDGET = 1.0 / 24.0
#: Healthy channel-hours the monitor simulates for a threshold when no calibration file is given
#: (``IN_CALL_CHANNEL_HOURS / m`` hours of an m-channel model: the cost and the number of alarms to
#: fit do not depend on m; 4 h for the 3-channel EHA).
IN_CALL_CHANNEL_HOURS = 12.0
#: The EHA's (3 channels) in-call hours.
IN_CALL_HOURS = 4.0


def in_call_hours(channels: int) -> float:
    """Hours of healthy data the monitor simulates in-call for an ``channels``-channel model."""
    return IN_CALL_CHANNEL_HOURS / max(1, int(channels))


#: Seconds of chattering per generated block (fixed: the numbers do not depend on anything else).
BLOCK_S = 600.0
#: Salt of the healthy streams' seeds (disjoint from the scenario simulations of the same seed).
ALARM_SALT = 0xA1A3

_CACHE: dict[str, RuleCalibration] = {}


def frames_per_hour(settings: MonitorSettings, dt: float) -> float:
    """STFT frames per hour of data: ``3600 / (hop samples * dt)``.

    Parameters
    ----------
    settings : MonitorSettings
        Gives the STFT hop.
    dt : float
        Sampling time (s).
    """
    return 3600.0 / (settings.stft.n_hop(dt) * dt)


def healthy_chattering(model: Model, n_samples: int, seed: int) -> Iterator[np.ndarray]:
    """Healthy chattering of a linear full-measurement ``model``, ``(K, m)`` blocks, ``n_samples`` in all.

    The exact MA(1) law of the module docstring; block ``b`` (``BLOCK_S`` seconds) draws its noise
    from ``SeedSequence([seed, ALARM_SALT, b])`` and the measurement noise at a block's first sample
    continues from the previous block, so the stream is one continuous healthy record.
    """
    from ..detection.spectral import chattering_autocovariance
    from ..plants.simulate import covariance_sqrt

    model = spectrum_model(model)
    chattering_autocovariance(model)  # full measurement (clear errors otherwise)
    C = model.C
    M = C @ model.A @ model.C_inv
    LQ = C @ covariance_sqrt(model.Q)
    LR = covariance_sqrt(model.R)
    n, m = model.n_states, model.n_outputs
    K = max(1, round(BLOCK_S / model.dt))
    v_prev = None
    done, b = 0, 0
    while done < n_samples:
        k = min(K, n_samples - done)
        rng = np.random.default_rng(np.random.SeedSequence([int(seed), ALARM_SALT, b]))
        # channel-major (m, k): the small matrix products run along the long axis
        v = LR @ rng.standard_normal((m, k + 1))
        if v_prev is not None:
            v[:, 0] = v_prev
        e = LQ @ rng.standard_normal((n, k))
        e += v[:, 1:]
        e -= M @ v[:, :-1]
        v_prev = v[:, -1].copy()
        done += k
        b += 1
        yield np.ascontiguousarray(e.T)


def monitor_score(
    model: Model, settings: MonitorSettings, threshold: Threshold | None = None
) -> tuple[FrameScore, Threshold]:
    """The monitor's frame score for ``settings`` and the per-frame threshold it carries the law of.

    Parameters
    ----------
    model : LinearModel or NonlinearModel
        The monitor's model.
    settings : MonitorSettings
        Without a threshold: the model's analytic per-frame threshold (exact law); with one: that
        threshold restricted to the band (a calibration's normalization, exponential law).
    threshold : Threshold, optional
        That per-frame threshold (:func:`~chatterspec.detection.thresholds.monitor_threshold` of
        ``model`` and ``settings``) when the caller has it already; computed here by default.
    """
    th = monitor_threshold(model, settings) if threshold is None else threshold
    return FrameScore(th), th


#: Most frame scores (frames x channels) one calibration holds in memory (float64: 256 MiB; the
#: concatenation briefly doubles it): the upper bound of its hours (621 h for the 3-channel EHA at a
#: 0.2 s hop; about 20 minutes of CPU on the numpy path).
MAX_SCORES = 1 << 25
#: Fewest frames per healthy stream: a rule's calibration counts its alarms over at least two steps.
MIN_FRAMES = 2


def _stream_frames(
    model: Model, settings: MonitorSettings, hours: float, scenario: Scenario | None
) -> tuple[int, int]:
    """``(streams, frames per stream)`` of ``hours`` of healthy data (module docstring)."""
    dt = model.dt
    W, H = settings.stft.n_window(dt), settings.stft.n_hop(dt)
    if is_linear(model):
        n = round(hours * 3600.0 / dt)
        return 1, (n - W) // H + 1 if n >= W else 0
    if scenario is None or not scenario.is_healthy:
        raise ParameterError(
            "the healthy frame scores of a nonlinear model come from simulated records: pass its "
            "healthy scenario (e.g. eha4-healthy)"
        )
    per = (scenario.n_samples - 1 - W) // H + 1
    if per < 1:
        raise ParameterError(f"records of {scenario.name!r} are shorter than one STFT window")
    return max(1, math.ceil(hours * 3600.0 / (per * H * dt))), per


def check_hours(
    model: Model, settings: MonitorSettings, hours: float, scenario: Scenario | None = None
) -> float:
    """``hours`` of healthy data if the alarm calibration can compute them, else one clear error.

    At least :data:`MIN_FRAMES` STFT frames per stream, and at most :data:`MAX_SCORES` frame scores
    in all (memory and time: the bound is said in hours of this model).

    Raises
    ------
    ParameterError
        ``hours`` not positive and finite, too short for two frames, or beyond the bound.
    """
    hours = positive("hours", hours, unit="h")
    streams, per = _stream_frames(model, settings, hours, scenario)
    stft, m = settings.stft, model.n_outputs
    if per < MIN_FRAMES:
        need_s = stft.window_s + (MIN_FRAMES - 1) * stft.hop_s
        raise ParameterError(
            f"{hours:g} h ({3600 * hours:.3g} s) of healthy data give {max(per, 0)} STFT frame(s) of "
            f"{stft.window_s:g} s (hop {stft.hop_s:g} s); the alarm calibration needs at least {MIN_FRAMES}: "
            f"give at least {need_s / 3600:.2g} h (--alarm-hours)"
        )
    if streams * per * m > MAX_SCORES:
        max_h = hours * MAX_SCORES / (streams * per * m)
        raise ParameterError(
            f"{hours:g} h of healthy data are more than the alarm calibration can hold: "
            f"{streams * per:.3g} frames x {m} channel(s) of scores, at most {MAX_SCORES:.3g} "
            f"({MAX_SCORES * 8 >> 20} MiB); give at most {max_h:.4g} h for this model (--alarm-hours)"
        )
    return hours


def healthy_frame_scores(
    model: Model,
    settings: MonitorSettings,
    hours: float,
    seed: int = 0,
    *,
    scenario: Scenario | None = None,
    progress: bool | None = None,
    threshold: Threshold | None = None,
) -> np.ndarray:
    """Frame scores of healthy data as the monitor computes them: ``(streams, frames, m)``.

    Parameters
    ----------
    model : LinearModel or NonlinearModel
        The monitor's nominal model.
    settings : MonitorSettings
        STFT, band and threshold (which carries the law of the score).
    hours : float
        Hours of healthy data (> 0, within :func:`check_hours`).
    seed : int
        Root seed.
    scenario : Scenario, optional
        A healthy scenario of ``model`` (required for a nonlinear model: its records are
        simulated, one stream each; ignored for a linear one).
    progress : bool, optional
        A progress bar on stderr (None: when stderr is a terminal).
    threshold : Threshold, optional
        The monitor's per-frame threshold for ``settings``, when the caller has it (see
        :func:`monitor_score`).
    """
    from ..progress import Progress

    hours = check_hours(model, settings, hours, scenario)
    score, _ = monitor_score(model, settings, threshold)
    dt = model.dt
    W, H = settings.stft.n_window(dt), settings.stft.n_hop(dt)
    compiled = _jit.enabled()  # the compiled taper/power loops, or their numpy form (same bits)
    label = "healthy data for the alarm threshold"
    if is_linear(model):
        n = round(hours * 3600.0 / dt)
        local = threading.local()

        def frames(x: np.ndarray, first: int) -> np.ndarray:
            eng = getattr(local, "engine", None)  # an engine's scratch buffers are per thread
            if eng is None:
                eng = local.engine = FrameEngine(settings.stft, dt, compiled=compiled)
            idx, P = eng(x, first)
            return score(P) if idx.size else np.zeros((0, model.n_outputs))

        # the chattering is drawn in order (its noise carries over blocks); the frames of each block
        # (with the previous block's last W - H samples) are cut and scored on worker threads
        jobs = []
        blocks = -(-n // max(1, round(BLOCK_S / dt)))
        with (
            Progress(blocks, label, enabled=progress) as bar,
            ThreadPoolExecutor(max_workers=max(1, min(4, os.cpu_count() or 1))) as pool,
        ):
            tail, start = np.zeros((0, model.n_outputs)), 0
            for e in healthy_chattering(model, n, seed):
                x = np.concatenate([tail, e]) if tail.shape[0] else e
                jobs.append(pool.submit(frames, x, start))
                n_frames = (start + x.shape[0] - W) // H + 1 if start + x.shape[0] >= W else 0
                nxt = max(start, n_frames * H)
                tail, start = x[nxt - start :], nxt
                bar.update(1)
            out = [j.result() for j in jobs]
        return np.concatenate(out)[None]
    from ..detection.pipeline import iter_chattering

    runs, _ = _stream_frames(model, settings, hours, scenario)
    assert scenario is not None  # _stream_frames refuses a nonlinear model without its scenario
    parts = []
    root = np.random.SeedSequence([int(seed), ALARM_SALT])
    engine = FrameEngine(settings.stft, dt, compiled=compiled)
    with Progress(runs, label, enabled=progress) as bar:
        for rec in iter_chattering(scenario, runs, root):
            _, P = engine(rec.values, 0)
            parts.append(score(P))
            bar.update(1)
    return np.concatenate(parts)


def display_alpha(rule: AlarmRule, default: float) -> float:
    """The per-frame level of the verdict drawn beside a rule: ``exp(-h)`` for a rule thresholding
    each step's score (frame, persistence: red frames = steps over the rule's threshold), ``default`` for
    one on an accumulated statistic (CUSUM)."""
    if not rule_spec(rule).accumulates and math.isfinite(rule.threshold):
        a = math.exp(-rule.threshold)
        if 0.0 < a < 1.0:
            return a
    return default


#: Sub-folder of the user cache (:mod:`chatterspec._cache`) holding in-call alarm calibrations.
CACHE_KIND = "alarm-calibrations"


def _key(
    model: Model,
    settings: MonitorSettings,
    rule: AlarmRule,
    X: float,
    hours: float,
    seed: int,
    sc: Scenario | None,
    confidence: float,
) -> dict[str, Any]:
    """Everything that determines :func:`calibrate_alarm`'s result, JSON-ready (the cache key)."""
    import scipy

    from .. import __version__

    th = settings.threshold
    return {
        "model": model.fingerprint(),  # A, B, C, Q, R, dt (a nonlinear model: its functions' code too)
        "stft": [float(settings.stft.window_s), float(settings.stft.hop_s), str(settings.stft.window)],
        "band": None if settings.band is None else [float(b) for b in settings.band],
        "alpha": float(settings.alpha),
        "correction": str(settings.correction),
        "threshold": None
        if th is None
        else hashlib.sha256(np.ascontiguousarray(th.values).tobytes()).hexdigest(),
        "rule": {"rule": rule.name, **rule.parameters()},  # its threshold is what is computed
        "false_alarms_per_hour": float(X),
        "hours": float(hours),
        "seed": int(seed),  # np.int64(3) is the seed 3
        "scenario": None if sc is None else sc.name,
        "confidence": float(confidence),
        # the code that drew and scored the streams: results may differ across versions
        "versions": {"chatterspec": __version__, "numpy": np.__version__, "scipy": scipy.__version__},
        "compiled": _jit.enabled(),
    }


def calibrate_alarm(
    model: Model,
    settings: MonitorSettings,
    rule: AlarmRule | str,
    false_alarms_per_hour: float,
    *,
    hours: float | None = None,
    seed: int = 0,
    scenario: Scenario | None = None,
    confidence: float = 0.95,
    note: Callable[[str], None] | None = None,
    progress: bool | None = None,
    threshold: Threshold | None = None,
) -> RuleCalibration:
    """Threshold of ``rule`` for the monitor of ``model`` at ``false_alarms_per_hour`` (module docstring).

    The result of a linear model is kept in the user cache (:mod:`chatterspec._cache`: keyed by
    the model's matrices, the detector and alarm settings, ``hours``, ``seed``, ``confidence`` and
    the versions of the code), so the next process reads it instead of simulating again; a
    nonlinear model's only in this process (its healthy scenario is not part of the key).

    Parameters
    ----------
    model : LinearModel or NonlinearModel
    settings : MonitorSettings
        STFT, band and per-frame threshold of the monitor (the score's law).
    rule : rule or str
        An alarm rule (its other parameters are kept) or a rule name (table defaults).
    false_alarms_per_hour : float
        The budget (> 0, finite): alarm starts per hour, all channels together; at most one start
        per two frames per channel (:func:`~chatterspec.detection.alarms.calibration.check_budget`).
    hours, seed, scenario
        Healthy data simulated (see :func:`healthy_frame_scores`; ``hours`` default
        :func:`in_call_hours`, bounded by :func:`check_hours`); not used by the frame rule with
        the exact law.
    confidence : float
        Level of the intervals.
    note : callable, optional
        Called with one line of text when the calibration is computed rather than read back
        (what is simulated, and where the result is cached).
    progress : bool, optional
        A progress bar on stderr while the healthy data are simulated (None: when stderr is a
        terminal).
    threshold : Threshold, optional
        The monitor's per-frame threshold for ``settings``
        (:func:`~chatterspec.detection.thresholds.monitor_threshold`) when the caller has it already
        (e.g. to build the monitor with it too); computed here by default.
    """
    from .. import _cache

    dt = model.dt
    F = frames_per_hour(settings, dt)
    X = check_budget(false_alarms_per_hour, steps_per_hour=F, channels=model.n_outputs)
    rule = make_rule(rule) if isinstance(rule, str) else rule
    score, _ = monitor_score(model, settings, threshold)
    if rule_spec(rule).per_step_law and score.law == "exact":
        return law_frame_rule(F, model.n_outputs, X, confidence)
    hours = check_hours(model, settings, in_call_hours(model.n_outputs) if hours is None else hours, scenario)
    key = _key(model, settings, rule, X, hours, seed, scenario, confidence)
    text = _cache.canonical(key)
    cached = _CACHE.get(text)
    if cached is not None:
        return cached
    on_disk = is_linear(model)  # a nonlinear model's streams depend on its scenario, not in the key
    cal = _from_cache(key) if on_disk else None
    if cal is None:
        if note is not None:
            where = _cache.cache_dir()
            if not on_disk:
                how = "not cached: a nonlinear model's"
            elif where is None:
                how = f"not cached: {_cache.NO_CACHE_ENV} is set"
            else:
                how = f"first run for this model and settings; cached in {where / CACHE_KIND}"
            note(
                f"calibrating the {rule.name} alarm threshold of {model.name!r} on {hours:g} h of simulated "
                f"healthy data ({how})"
            )
        scores = healthy_frame_scores(
            model, settings, hours, seed, scenario=scenario, progress=progress, threshold=threshold
        )
        cal = calibrate_rule(rule, scores, F, X, confidence=confidence, seed=int(seed))
        if on_disk:
            saved = _cache.store(CACHE_KIND, key, cal.to_dict())
            if isinstance(saved, str) and note is not None and _cache.cache_dir() is not None:
                note(f"the alarm calibration was not cached: {saved}")
    if len(_CACHE) > 64:
        _CACHE.clear()
    _CACHE[text] = cal
    return cal


def _from_cache(key: dict[str, Any]) -> RuleCalibration | None:
    """The cached calibration of ``key``, if there is a valid one (else None: computed again)."""
    from .. import _cache

    doc = _cache.load(CACHE_KIND, key)
    if doc is None:
        return None
    try:
        cal = RuleCalibration.from_dict(doc)
    except (ParameterError, AttributeError, TypeError):
        return None
    # an entry for this key is this key's calibration: the same rule, budget and hours
    if (
        {"rule": cal.rule.name, **cal.rule.parameters()} != key["rule"]
        or cal.false_alarms_per_hour != key["false_alarms_per_hour"]
        or not math.isfinite(cal.threshold)
    ):
        return None
    return cal


def check_alarm_calibration(
    calibration: RuleCalibration,
    rule: str | None = None,
    false_alarms_per_hour: float | None = None,
    parameters: Mapping[str, Any] | None = None,
    source: object = "the calibration",
) -> RuleCalibration:
    """``calibration`` if it was made for ``rule``, the budget and the rule's ``parameters``.

    A calibration records its rule (with parameters), budget and frames per hour; it is refused
    for another rule, budget or parameter value (``None`` / missing: not checked).

    Parameters
    ----------
    calibration : RuleCalibration
    rule : str, optional
        The rule name asked for.
    false_alarms_per_hour : float, optional
        The budget asked for.
    parameters : mapping, optional
        Rule parameters asked for (``k``, ``n``, ``drift``).
    source : object
        How to name the calibration in the message (e.g. its file).

    Raises
    ------
    CalibrationMismatchError
        It was made for another rule, budget or parameter.
    """
    file_rule = calibration.rule
    if rule is not None and rule != file_rule.name:
        raise CalibrationMismatchError(
            f"{source} was calibrated for the {file_rule.name} rule; got --rule {rule} "
            f"(calibrate again with --rule {rule})"
        )
    if false_alarms_per_hour is not None and not math.isclose(
        float(false_alarms_per_hour), calibration.false_alarms_per_hour, rel_tol=1e-9
    ):
        raise CalibrationMismatchError(
            f"{source} was calibrated for {calibration.false_alarms_per_hour:g} false alarms per hour; got "
            f"--false-alarms-per-hour {float(false_alarms_per_hour):g}"
        )
    mine = file_rule.parameters()
    for k, v in (parameters or {}).items():
        if mine.get(k) != v:
            raise CalibrationMismatchError(
                f"{source} was calibrated for the {file_rule.name} rule with {k} = {mine.get(k)}; got {v}"
            )
    return calibration


def alarm_settings(
    model: Model,
    settings: MonitorSettings,
    rule: str | None = None,
    false_alarms_per_hour: float | None = None,
    *,
    hours: float | None = None,
    seed: int = 0,
    scenario: Scenario | None = None,
    calibration: RuleCalibration | None = None,
    note: Callable[[str], None] | None = None,
    progress: bool | None = None,
    threshold: Threshold | None = None,
    **parameters: float,
) -> Any:
    """``settings`` with an alarm rule whose threshold meets ``false_alarms_per_hour``.

    Parameters
    ----------
    model : LinearModel or NonlinearModel
    settings : MonitorSettings
    rule : {"frame", "persistence", "cusum"}, optional
        Default :data:`DEFAULT_RULE` (with ``calibration``: its rule, and another one is refused).
    false_alarms_per_hour : float, optional
        Default :data:`DEFAULT_BUDGET`, one per day (with ``calibration``: its budget, and another
        one is refused).
    hours, seed, scenario, note, progress
        See :func:`calibrate_alarm`.
    calibration : RuleCalibration, optional
        A ready threshold (e.g. from a calibration file): used as is, after
        :func:`check_alarm_calibration` against ``rule``, the budget and ``parameters``.
    threshold : Threshold, optional
        The monitor's per-frame threshold for ``settings``, passed to :func:`calibrate_alarm`.
    **parameters
        The rule's parameters (``k``, ``n``; ``drift``).

    Raises
    ------
    ParameterError
        Bad budget or rule parameters.
    CalibrationMismatchError
        ``calibration`` was made for another rule, budget or parameters.

    Returns
    -------
    MonitorSettings
        ``rule`` and ``budget`` set; for the frame and persistence rules ``alpha`` is
        :func:`display_alpha` (the drawn per-frame verdict is the rule's per-step exceedance).
    """
    if calibration is None:
        r = make_rule(rule or DEFAULT_RULE, **parameters)
        X = DEFAULT_BUDGET if false_alarms_per_hour is None else false_alarms_per_hour
        calibration = calibrate_alarm(
            model, settings, r, X, hours=hours, seed=seed, scenario=scenario, note=note, progress=progress,
            threshold=threshold,
        )  # fmt: skip
    else:
        check_alarm_calibration(calibration, rule, false_alarms_per_hour, parameters)
    r = calibration.rule
    alpha = settings.alpha if settings.threshold is not None else display_alpha(r, settings.alpha)
    return replace(settings, rule=r, budget=calibration, alpha=alpha)


@dataclass(frozen=True)
class Shifted:
    """``signal`` in the time frame of an onset: ``u(t) = signal((t - shift) mod period)``.

    ``period`` None: no wrap (a ``Step`` before ``shift`` keeps its initial value).
    """

    signal: Any
    shift: float
    period: float | None = None

    def sample(self, t: np.ndarray) -> np.ndarray:
        """The values at the given times (s), one row per time."""
        x = np.asarray(t, dtype=float) - self.shift
        if self.period:
            x = np.mod(x, self.period)
        return self.signal.sample(x)

    def describe(self) -> str:
        """A short description for reports and recordings."""
        wrap = f", repeated every {self.period:g} s" if self.period else ""
        return f"{self.signal.describe()} from t = {self.shift:g} s{wrap}"


def onset_scenarios(
    name: str | Scenario,
    *,
    healthy_s: float = 6.0,
    fault_s: float = 8.0,
    phases: Sequence[float] = (0.0, 0.5, 1.0, 1.5, 2.0, 2.5, 3.0, 3.5),
) -> list[Scenario]:
    """Onset versions of catalogue fault ``name`` (see the module docstring).

    Parameters
    ----------
    name : str or Scenario
        A faulty catalogue scenario (or a Scenario built like one): a whole-record fault
        (``eha-leak-minor``, ...) or a timeline (``so-timeline-constant``, ...).
    healthy_s : float
        Healthy stretch before the onset (s); it must exceed one STFT window.
    fault_s : float
        Fault duration of a whole-record fault (s); a timeline window keeps its own.
    phases : sequence of float
        Whole-record faults: times into the scenario's input (s) at which the onset falls
        (the input repeats with the scenario's duration).
    """
    from ..plants.scenarios import Scenario, Segment, scenario

    base = name if isinstance(name, Scenario) else scenario(name)
    name = base.name
    if base.is_healthy:
        raise ParameterError(f"{name!r} is healthy: no onset")
    out = []
    if base.windows:
        for w in base.windows:
            d = w.stop - w.start
            out.append(
                Scenario(
                    name=f"{name}@{w.start:g}s",
                    nominal=base.nominal,
                    input=Shifted(base.input, healthy_s - w.start),
                    duration=healthy_s + d + 1.0,
                    windows=(Segment(healthy_s, healthy_s + d, w.model, w.label),),
                    fault=base.fault,
                    level=w.label,
                    fault_channel=base.fault_channel,
                )
            )
        return out
    for ph in phases:
        out.append(
            Scenario(
                name=f"{name}@phase{ph:g}s",
                nominal=base.nominal,
                input=Shifted(base.input, healthy_s - float(ph), base.duration),
                duration=healthy_s + fault_s,
                windows=(
                    Segment(healthy_s, healthy_s + fault_s, cast(Model, base.plant), base.level),
                ),  # (set)
                fault=base.fault,
                level=base.level,
                fault_channel=base.fault_channel,
            )
        )
    return out


@dataclass(frozen=True)
class DelayResult:
    """Delays of one rule over onset scenarios.

    Attributes
    ----------
    delays_s : (runs,) array
        Per run (all scenarios together), the delay (s); ``inf`` for a miss.
    on_fault_channel : (runs,) bool array
        The first alarm after the onset is on the scenario's fault channel.
    false_starts : int
        Alarm starts before the onset (healthy stretch).
    healthy_hours : float
        Healthy time observed before the onsets, all runs (h).
    """

    delays_s: np.ndarray
    on_fault_channel: np.ndarray
    false_starts: int
    healthy_hours: float

    @property
    def detected(self) -> float:
        """Fraction of runs whose fault was detected (finite delay)."""
        return float(np.mean(np.isfinite(self.delays_s)))

    def quantile(self, q: float) -> float:
        """Delay quantile (s) over all runs, misses counted as ``inf``."""
        d = np.sort(self.delays_s)
        k = min(d.size - 1, max(0, math.ceil(q * d.size) - 1))
        return float(d[k])

    def to_dict(self) -> dict[str, Any]:
        """The fields as a JSON-ready dict (what the JSON outputs print)."""
        med, p90, mx = (finite_or_none(self.quantile(q)) for q in (0.5, 0.9, 1.0))
        return {
            "runs": int(self.delays_s.size),
            "detected": self.detected,
            "median_s": med,
            "p90_s": p90,
            "max_s": mx,
            "on_fault_channel": float(np.mean(self.on_fault_channel)),
            "false_starts_before_onset": self.false_starts,
            "healthy_hours": self.healthy_hours,
        }


def score_delays(
    S: np.ndarray,
    t: np.ndarray,
    interval: tuple[float, float],
    rules: Mapping[str, AlarmRule],
    cfg: STFTConfig,
    dt: float,
    fault_channel: int = -1,
) -> dict[str, tuple[np.ndarray, np.ndarray, int, float]]:
    """Delays of each rule on the frame scores of onset records (module docstring's definitions).

    Parameters
    ----------
    S : (runs, F, m) array
        Frame scores of records whose chattering samples are at times ``t``.
    t : (N,) array
        Times (s) of the chattering samples.
    interval : (float, float)
        Fault onset and end (s).
    rules : mapping label -> rule
        Rules with their thresholds set.
    cfg : STFTConfig
        The frames' window and hop.
    dt : float
        Sampling time (s).
    fault_channel : int
        Index of the fault's channel (-1: none).

    Returns
    -------
    dict label -> (delays (runs,), on fault channel (runs,), false starts before the onset, healthy hours)
    """
    on, off = interval
    W, H = cfg.n_window(dt), cfg.n_hop(dt)
    F = S.shape[1]
    t_end = t[np.arange(F) * H + W - 1]
    t_start = t[np.arange(F) * H]
    valid = (t_end >= on - 1e-9) & (t_start < off)
    pre = t_end < on - 1e-9
    healthy_h = S.shape[0] * float(np.count_nonzero(pre)) * H * dt / 3600.0
    out = {}
    for label, rule in rules.items():
        st = run_rule(rule, S).starts  # (runs, F, m)
        any_st = st.any(axis=-1)
        hit = any_st & valid
        first = np.where(hit.any(axis=1), np.argmax(hit, axis=1), -1)
        d = np.where(first >= 0, t_end[np.maximum(first, 0)] - on, np.inf)
        ch = np.array(
            [fault_channel >= 0 and f >= 0 and bool(st[r, f, fault_channel]) for r, f in enumerate(first)],
            dtype=bool,
        )
        out[label] = (d, ch, int(np.count_nonzero(st[:, pre])), healthy_h)
    return out


def alarm_delays(
    scenarios: Sequence[Scenario],
    rules: Mapping[str, AlarmRule],
    runs: int,
    seed: int = 0,
    *,
    settings: MonitorSettings | None = None,
) -> dict[str, DelayResult]:
    """Delays of each rule of ``rules`` on ``runs`` realizations of every onset scenario.

    Parameters
    ----------
    scenarios : sequence of Scenario
        Onset scenarios (:func:`onset_scenarios`), one fault window each, same nominal model.
    rules : mapping label -> rule
        Rules with their thresholds set (e.g. for a budget, by
        :func:`chatterspec.studies.alarm_budget.calibrate_alarm`).
    runs : int
        Realizations per scenario.
    seed : int
        Root seed; scenario ``i`` uses ``SeedSequence([seed, i])``.
    settings : MonitorSettings, optional
        The monitor's STFT, band and threshold (the score's law); default ``MonitorSettings()``.
    """
    from ..detection.alarms.calibration import MonitorSettings
    from ..detection.pipeline import iter_chattering

    settings = settings or MonitorSettings()
    cfg: STFTConfig = settings.stft
    acc: dict[str, dict[str, list[Any]]] = {k: {"d": [], "ch": [], "pre": [0]} for k in rules}
    healthy_h = 0.0
    for i, sc in enumerate(scenarios):
        if len(sc.fault_intervals) != 1:
            raise ParameterError(f"{sc.name}: an onset scenario has exactly one fault window")
        ((on, off),) = sc.fault_intervals
        model = sc.nominal
        score, _ = monitor_score(model, settings)
        fault_c = list(model.output_names).index(sc.fault_channel) if sc.fault_channel else -1
        for rec in iter_chattering(sc, runs, np.random.SeedSequence([int(seed), i])):
            _, P = frame_columns(rec.values, model.dt, cfg)
            part = score_delays(score(P), rec.t, (on, off), rules, cfg, model.dt, fault_c)
            for label, (d, ch, pre, _) in part.items():
                acc[label]["d"].append(d)
                acc[label]["ch"].append(ch)
                acc[label]["pre"][0] += pre
            healthy_h += next(iter(part.values()))[3] if part else 0.0
    return {
        k: DelayResult(np.concatenate(v["d"]), np.concatenate(v["ch"]), v["pre"][0], healthy_h)
        for k, v in acc.items()
    }
