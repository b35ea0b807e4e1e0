"""Fault identification in physical units: which parameter changed, by how much, with an interval.

The method (goes beyond the paper, which reads severity off spectral peaks)
---------------------------------------------------------------------------
With full measurement (C invertible) and zero initial error, the auxiliary sgn filter's
chattering is eq (23)::

    e(k+1) = z(k+1) - Phi z(k) - G u(k),           Phi = C A C^-1,  G = C B (nominal)

If the true plant has ``A + dA``, ``B + dB``, then with ``dPhi = C dA C^-1``, ``dG = C dB``::

    e(k+1) = dPhi z(k) + dG u(k) + eta(k+1),
    eta(k+1) = C v(k) + w(k+1) - Phi_t w(k)         (Phi_t: the true plant's C A C^-1)

so every channel's chattering is a linear regression of the deviations on the measured
states and the input, with a vector MA(1) error (the structure behind eq 56-58):
``E[eta eta'] = C Q C' + R + Phi_t R Phi_t'``, ``E[eta(k) eta(k+1)'] = -R Phi_t'``.

**Errors in variables.** ``z(k) = C x(k) + w(k)`` carries ``w(k)``, which also enters
``eta(k+1)``: ordinary least squares on z(k) is biased by ``-R Phi_t'`` times the inverse
regressor Gram. chatterspec uses **instrumental variables**: the instrument of ``z_j(k)`` is
``z_j(k-1)`` (independent of ``eta(k+1)``, strongly correlated with z_j(k)), an input is its own
instrument. The alternative, least squares corrected with the known R, needs R and the
unknown ``Phi_t`` and is biased as soon as the declared R is off; IV needs neither (the
comparison, measured, is in ``docs/paper-notes.md`` and ``scripts/identification_study.py``).

**Interval.** The estimate's covariance is the lag-1 sandwich
``A^-1 (Gamma0 S0 + Gamma1 S1 + Gamma1' S1') A^-T`` with the instrument Grams at lags 0 and 1
(``S0``, ``S1``) and the MA(1) autocovariances above at the fitted true plant (Newey-West
with the known lag and the known noise covariances). The MA(1) colour matters: the pressure
channel's ``eta`` is almost a first difference of white noise; treated as white, the leakage's
standard error comes out 3.7 times too large (measured on ``eha-leak-major``).

**Physical parameters.** The entries of ``[dPhi, dG]`` that some parameter enters (the
model's :class:`~chatterspec.plants.parameters.ParameterMap`) are estimated channel by
channel. Each hypothesis (a set of parameters) is fitted to them by minimum distance with the
estimates' covariance as weight (Gauss-Newton, exact in one step for entries affine in the
parameters); the estimate is the **plant's value** of the parameter (nominal + deviation), its
interval the delta-method Wald interval at ``confidence``; the minimum distance is the test of
the hypothesis (chi-squared with entries - parameters degrees of freedom).

**Isolation.** "no fault" is the Wald test of all deviations = 0 at ``alpha`` (chi-squared with
one degree of freedom per estimated entry). If it is not rejected, "no fault" is selected;
else the hypothesis with the fewest parameters that its own test does not reject at
``alpha`` (ties: the largest p-value); "unexplained" if every declared hypothesis is rejected.
With the detector's alpha, a healthy record selects "no fault" at the detector's false-alarm
rate.

**What cannot be identified.** Reduced-order measurement (C not invertible): the deviations
multiply unmeasured states (eq 24-28); :class:`~chatterspec.errors.IdentifiabilityError` says
which entries involve which unmeasured states. A regressor without excitation over the window
(an input identically zero, a measured state at the noise level): the entries it carries are
not estimated and a hypothesis that needs them gets no estimate, with the reason.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator, Sequence

import numpy as np

from .._validate import finite_array
from ..errors import ParameterError, ShapeError
from ..plants.models import LinearModel
from ..plants.nonlinear import Model
from ..plants.parameters import NO_FAULT, UNEXPLAINED, Hypothesis
from ._identification_fit import (
    IdentificationSetup,
    build_setup,
    check_alpha,
    fit_moments,
    true_hypothesis,
    true_parameters,
)
from ._identification_moments import IdentificationMoments, compute_moments
from .identification_results import (
    HypothesisTest,
    Identification,
    IdentificationReport,
    ParameterEstimate,
)
from .pipeline import ChatteringRecord

__all__ = [
    "NO_FAULT",
    "UNEXPLAINED",
    "HypothesisTest",
    "Identification",
    "IdentificationMoments",
    "IdentificationReport",
    "IdentificationSetup",
    "IdentificationStream",
    "ParameterEstimate",
    "identification_moments",
    "identification_setup",
    "identify",
    "identify_moments",
    "identify_record",
    "true_hypothesis",
    "true_parameters",
]


def identification_setup(
    model: Model, hypotheses: Sequence[Hypothesis | str | Sequence[str]] | None = None
) -> IdentificationSetup:
    """What identification estimates for ``model``: entries, regressors and hypotheses.

    Parameters
    ----------
    model : LinearModel
        Nominal model with full measurement and a ``parameter_map``.
    hypotheses : sequence, optional
        Declared hypothesis names, parameter names (one-parameter hypotheses), lists of
        parameter names (combinations, named ``"a+b"``) or
        :class:`~chatterspec.plants.parameters.Hypothesis`; default: the map's hypotheses.

    Raises
    ------
    IdentifiabilityError
        Nonlinear model, reduced-order measurement (the message says which entries involve
        unmeasured states), no parameter map, or parameters that cannot be told apart.
    ParameterError
        A hypothesis naming a parameter the model does not have; a map that does not
        reproduce the model's A and B.
    """
    return build_setup(model, hypotheses)


def _window(times_e: np.ndarray, window_s: tuple[float, float] | None, T: int) -> tuple[int, int]:
    """Regressor indices ``[ka, kb)`` whose chattering ``e(k+1)`` (at ``times_e[k]``) lies in the window."""
    ka, kb = 1, T - 1
    if window_s is not None:
        lo, hi = (float(x) for x in window_s)
        if not (np.isfinite(lo) and np.isfinite(hi) and hi > lo):
            raise ParameterError(
                f"window_s must be (start, stop) in seconds with start < stop; got {window_s!r}"
            )
        tol = 1e-9 * max(1.0, abs(hi))
        ka = max(ka, int(np.searchsorted(times_e, lo - tol, side="left")))
        kb = min(kb, int(np.searchsorted(times_e, hi - tol, side="left")))
    if kb - ka < 2:
        raise ParameterError(
            f"the identification window holds {max(kb - ka, 0)} chattering samples; it needs at least 2 "
            f"(record {times_e[0]:.6g}-{times_e[-1]:.6g} s, window {window_s})"
        )
    return ka, kb


def identification_moments(
    setup: IdentificationSetup,
    z: np.ndarray,
    u: np.ndarray,
    e: np.ndarray | None = None,
    *,
    window_s: tuple[float, float] | None = None,
    t0: float = 0.0,
) -> IdentificationMoments:
    """The sums identification needs over a time window, per realization (additive).

    Parameters
    ----------
    setup : IdentificationSetup
    z : (runs, T, m) or (T, m) array
        Measurements z(0) .. z(T-1) (one realization per leading index).
    u : (T, p), (runs, T, p) or (T,) array
        Inputs u(0) .. u(T-1) (u(k) drives the plant from sample k to k+1).
    e : (runs, T-1, m) array, optional
        The auxiliary filter's chattering ``e[:, k] = e(k+1|k)``; default its closed form
        eq (23) ``z(k+1) - Phi z(k) - G u(k)`` (zero initial error, chatterspec's default).
    window_s : (float, float), optional
        ``[start, stop)`` in seconds: the chattering samples used (default: the whole record
        except its first, which has no instrument).
    t0 : float
        Time (s) of ``z[..., 0, :]``.

    Raises
    ------
    ShapeError, NonFiniteError
        On inconsistent shapes or NaN/inf data.
    ParameterError
        A window holding fewer than 2 chattering samples.
    """
    return _moments(setup, z, u, e, window_s, t0, check=True)


def _moments(
    setup: IdentificationSetup,
    z: np.ndarray,
    u: np.ndarray,
    e: np.ndarray | None,
    window_s: tuple[float, float] | None,
    t0: float,
    check: bool,
) -> IdentificationMoments:
    """:func:`identification_moments`; ``check=False`` skips the finiteness checks (pipeline data)."""
    model = setup.model
    if not check:
        z = z[None] if z.ndim == 2 else z
        u = u[:, None] if u.ndim == 1 else u
        T = z.shape[1]
        times_e = t0 + np.arange(1, T) * model.dt
        ka, kb = _window(times_e, window_s, T)
        times = (times_e[ka], times_e[kb - 1] + model.dt)
        assert e is not None  # (the pipeline passes its chattering)
        return compute_moments(z, u, e, setup.J, setup.L, setup.R, ka, kb, times, setup.swe_pairs)
    z = finite_array("z", z, ndim=(2, 3))
    z = z[None] if z.ndim == 2 else z
    runs, T, m = z.shape
    if m != model.n_outputs or T < 4:
        raise ShapeError(f"z must have shape (runs, T >= 4, {model.n_outputs}); got {z.shape}")
    u = finite_array("u", u, ndim=(1, 2, 3))
    if u.ndim == 1:
        u = u[:, None]
    if u.shape[-2:] != (T, model.n_inputs) or (u.ndim == 3 and u.shape[0] != runs):
        raise ShapeError(
            f"u must have shape ({T}, {model.n_inputs}) or ({runs}, {T}, {model.n_inputs}); got {u.shape}"
        )
    if e is None:
        Phi, G = model.C @ model.A @ model.C_inv, model.C @ model.B
        e = z[:, 1:] - z[:, :-1] @ Phi.T - (u[..., :-1, :] @ G.T)
    else:
        e = finite_array("e", e, shape=(runs, T - 1, m))
    times_e = t0 + np.arange(1, T) * model.dt  # e[:, k] is at time t0 + (k+1) dt
    ka, kb = _window(times_e, window_s, T)
    times = (times_e[ka], times_e[kb - 1] + model.dt)
    return compute_moments(z, u, e, setup.J, setup.L, setup.R, ka, kb, times, setup.swe_pairs)


def identify_moments(
    setup: IdentificationSetup,
    moments: IdentificationMoments,
    *,
    alpha: float = 1e-3,
    confidence: float = 0.95,
) -> Identification:
    """Estimate, test and select from the sums of a window (every realization at once).

    Parameters
    ----------
    setup : IdentificationSetup
    moments : IdentificationMoments
        From :func:`identification_moments`; ``moments.total()`` pools the realizations.
    alpha : float
        Level of every hypothesis test (use the detector's: healthy records then select
        "no fault" at its false-alarm rate).
    confidence : float
        Level of the parameter intervals (default 95 %).
    """
    alpha, confidence = check_alpha(alpha, confidence)
    return Identification(setup, moments, alpha, confidence, fit_moments(setup, moments, alpha, confidence))


def identify(
    model: LinearModel,
    z: np.ndarray,
    u: np.ndarray,
    e: np.ndarray | None = None,
    *,
    hypotheses: Sequence[Hypothesis | str | Sequence[str]] | None = None,
    window_s: tuple[float, float] | None = None,
    t0: float = 0.0,
    alpha: float = 1e-3,
    confidence: float = 0.95,
) -> Identification:
    """Which physical parameter changed, by how much: every realization of ``z`` at once.

    Parameters
    ----------
    model : LinearModel
        Nominal model (full measurement) with a ``parameter_map``.
    z : (runs, T, m) or (T, m) array
        Measurements.
    u : (T, p), (runs, T, p) or (T,) array
        Inputs.
    e : (runs, T-1, m) array, optional
        The chattering (default: its closed form eq 23).
    hypotheses : sequence, optional
        See :func:`identification_setup`.
    window_s : (float, float), optional
        ``[start, stop)`` in seconds (e.g. an STFT fault interval); default the whole record.
    t0 : float
        Time (s) of the first sample of ``z``.
    alpha, confidence : float
        Test level and interval level.

    Returns
    -------
    Identification
        ``.report(run)`` for one record; ``.estimate(h)``, ``.interval(h)``, ``.selection_rate()``
        over the realizations.

    See Also
    --------
    identify_record : the same on a :class:`~chatterspec.detection.pipeline.ChatteringRecord`.
    chatterspec.detection.detect.detect_record : the spectral detector.
    """
    setup = identification_setup(model, hypotheses)
    mom = identification_moments(setup, z, u, e, window_s=window_s, t0=t0)
    return identify_moments(setup, mom, alpha=alpha, confidence=confidence)


def identify_record(
    record: ChatteringRecord,
    *,
    hypotheses: Sequence[Hypothesis | str | Sequence[str]] | None = None,
    window_s: tuple[float, float] | None = None,
    alpha: float = 1e-3,
    confidence: float = 0.95,
    setup: IdentificationSetup | None = None,
) -> Identification:
    """:func:`identify` on a chattering record that kept its measurements (``record.z``, ``record.u``).

    Parameters
    ----------
    record : ChatteringRecord
        Chattering ``values`` with ``z`` and ``u`` (its time axis gives the window's times).
    hypotheses : sequence, optional
        See :func:`identification_setup` (ignored when ``setup`` is given).
    window_s : (float, float), optional
        ``[start, stop)`` in seconds; default the whole record.
    alpha, confidence : float
        Test level and interval level.
    setup : IdentificationSetup, optional
        A setup built once for many records (e.g. the chunks of a study).

    Raises
    ------
    ParameterError
        If the record holds no measurements (``iter_chattering(..., measurements=True)`` keeps them).
    """
    if record.z is None or record.u is None:
        raise ParameterError(
            "this chattering record did not keep its measurements: build it with chattering_record(...) or "
            "iter_chattering(..., measurements=True)"
        )
    setup = setup or identification_setup(record.model, hypotheses)
    t0 = float(record.t[0]) - record.dt
    # the pipeline's arrays are finite (the simulation and filters check their inputs)
    mom = _moments(setup, record.z, record.u, record.values, window_s, t0, check=False)
    return identify_moments(setup, mom, alpha=alpha, confidence=confidence)


class IdentificationStream:
    """Identification over a stream of chattering chunks (e.g. those ``detect`` consumes).

    :meth:`tap` passes the chunks through unchanged while it identifies each one; then
    :meth:`result` gives every realization's identification and :meth:`pooled` the estimate
    from all realizations together (their sums added), with the per-record selection rates.

    Parameters
    ----------
    setup : IdentificationSetup
    window_s : (float, float), optional
    alpha, confidence : float
    """

    def __init__(
        self,
        setup: IdentificationSetup,
        *,
        window_s: tuple[float, float] | None = None,
        alpha: float = 1e-3,
        confidence: float = 0.95,
    ) -> None:
        self.setup = setup
        self.window_s = window_s
        self.alpha, self.confidence = check_alpha(alpha, confidence)
        self._parts: list[Identification] = []
        self._total: IdentificationMoments | None = None

    def tap(
        self, chunks: Iterable[ChatteringRecord], *, background: bool = False
    ) -> Iterator[ChatteringRecord]:
        """Yield ``chunks`` unchanged, identifying each (it must keep its measurements).

        With ``background``, a record is identified on a worker thread while the consumer works on
        it (numpy releases the GIL in both: the identification uses a core the single-threaded
        detector leaves idle); the tap waits for it before it asks for the next record, so a
        reused measurement buffer (``iter_chattering(..., reuse_measurements=True)``) is safe and
        the results are the same as without.
        """
        if not background:
            for rec in chunks:
                self.add(self._identify(rec))
                yield rec
            return
        from concurrent.futures import ThreadPoolExecutor

        with ThreadPoolExecutor(max_workers=1, thread_name_prefix="identify") as pool:
            for rec in chunks:
                job = pool.submit(self._identify, rec)
                try:
                    yield rec
                finally:
                    self.add(job.result())

    def _identify(self, rec: ChatteringRecord) -> Identification:
        return identify_record(
            rec, window_s=self.window_s, alpha=self.alpha, confidence=self.confidence, setup=self.setup
        )

    def add(self, part: Identification) -> None:
        """Add one chunk's identification (chunks in order), e.g. computed on a worker process."""
        self._parts.append(part)
        tot = part.moments.total()
        self._total = tot if self._total is None else self._total.add_records(tot)

    def result(self) -> Identification:
        """Every realization's identification, in order."""
        if not self._parts:
            raise ParameterError("no chunk has been identified yet")
        if len(self._parts) == 1:
            return self._parts[0]
        first = self._parts[0]
        fit = {k: np.concatenate([p.fit[k] for p in self._parts]) for k in first.fit}
        mom = _concat_moments([p.moments for p in self._parts])
        return Identification(self.setup, mom, self.alpha, self.confidence, fit)

    def pooled(self) -> IdentificationReport:
        """The estimate from every realization's sums together, with the single-record selection rates."""
        if self._total is None:
            raise ParameterError("no chunk has been identified yet")
        pooled = identify_moments(self.setup, self._total, alpha=self.alpha, confidence=self.confidence)
        return pooled.report(0, selection_rate=self.result().selection_rate())


def _concat_moments(parts: list[IdentificationMoments]) -> IdentificationMoments:
    a = parts[0]
    return IdentificationMoments(
        **{
            k: np.concatenate([getattr(p, k) for p in parts])
            for k in ("swx", "swe", "s0", "s1", "w_first", "w_last")
        },
        n_samples=a.n_samples,
        t_start=a.t_start,
        t_stop=a.t_stop,
        records=a.records,
    )
