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

The sums (moments)
------------------
Sums of products that fault identification needs, per realization and window.

Identification regresses the chattering ``e(k+1)`` on regressors ``x(k) = [z_J(k), u_L(k)]``
with instruments ``w(k) = [z_J(k-1), u_L(k)]`` (the method above).
Everything it needs from the data is four sums over the window's sample indices ``k``::

    Swx = sum w(k) x(k)'      Swe = sum w(k) e_R(k+1)'
    S0  = sum w(k) w(k)'      S1  = sum w(k) w(k+1)'     (pairs inside the window)

plus the instrument vectors at the window's first and last sample, so that the sums of two
adjacent windows add up exactly to the sums of their union (the online form adds hops).
The sums are additive over realizations too (the pooled estimate of many records).

They are computed as dot products of channel-major rows (``numpy.vecdot``, vectorized;
the views need no copy when the data are stored channel by channel, as the fused
simulation kernel writes them).

Setup and estimation
--------------------
What identification estimates for a model, and the estimation itself.

The :class:`IdentificationSetup` (entries, regressors and hypotheses of one model) and
:func:`fit_moments` (instrumental variables, the lag-1 sandwich covariance, the
minimum-distance fit of each hypothesis and the selection), vectorized over realizations.

Results
-------
Results of fault identification: per-parameter estimates, hypothesis tests, reports.

:class:`Identification` holds every realization's numbers (arrays, realizations leading);
:meth:`Identification.report` gives the :class:`IdentificationReport` of one record (or of
the pooled sums of many), with ``.table()`` and ``.to_dict()`` (estimates rounded to two
significant digits of their standard error).

Online
------
Fault identification online: an estimate and its interval per STFT hop, in bounded memory.

:class:`OnlineIdentifier` takes the same raw pushes as the online monitor
(:class:`chatterspec.online.monitor.ChatteringMonitor`): measurements ``z (K, m)`` and inputs
``u (K, p)``. It cuts the stream into blocks of one hop and keeps the identification sums of
the last ``window`` blocks (:class:`~chatterspec.detection.identification.IdentificationMoments`
add exactly over adjacent blocks); each completed block closes a window, which is identified.
Every block and window of one push is computed in one vectorized call, so a file replayed in
large pushes costs about as much per hop as a live stream pushed hop by hop. The numbers do not
depend on how the stream is cut into pushes.

Window of hop ``j``: the regressor indices ``1 + j H .. j H + W`` (``H`` samples per hop, ``W = n H``
per window): the samples of the monitor's frame ``j`` shifted by one (the first chattering sample
has no instrument).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np
import scipy.special

from .._validate import finite_array, positive_int
from ..errors import IdentifiabilityError, ParameterError, ShapeError
from ..plants.models import LinearModel
from ..plants.nonlinear import Model, is_linear
from ..plants.parameters import NO_FAULT, UNEXPLAINED, Hypothesis, ParameterMap

if TYPE_CHECKING:  # pragma: no cover - the pipeline (simulation, scenarios) is not needed to identify
    from .pipeline import ChatteringRecord

__all__ = [
    "METHOD",
    "NO_FAULT",
    "UNEXPLAINED",
    "HypothesisTest",
    "Identification",
    "IdentificationMoments",
    "IdentificationReport",
    "IdentificationSetup",
    "IdentificationStream",
    "OnlineIdentification",
    "OnlineIdentifier",
    "ParameterEstimate",
    "hop_windows",
    "identification_moments",
    "identification_setup",
    "identify",
    "identify_moments",
    "identify_record",
    "true_hypothesis",
    "true_parameters",
]


@dataclass(frozen=True, eq=False)
class IdentificationMoments:
    """The sums of one window for ``runs`` realizations (leading axis).

    Attributes
    ----------
    swx, s0, s1 : (runs, q, q) arrays
        ``sum w x'``, ``sum w w'``, ``sum w(k) w(k+1)'``.
    swe : (runs, q, r) arrays
        ``sum w e_R(k+1)'``.
    w_first, w_last : (runs, q) arrays
        Instrument vector at the window's first and last sample index.
    n_samples : int
        Number of sample indices k in the window (per realization).
    t_start, t_stop : float
        Times (s) of the first and one past the last chattering sample ``e(k+1)`` used.
    records : int
        Realizations summed into each row (1, or R for a pooled total).
    """

    swx: np.ndarray
    swe: np.ndarray
    s0: np.ndarray
    s1: np.ndarray
    w_first: np.ndarray
    w_last: np.ndarray
    n_samples: int
    t_start: float
    t_stop: float
    records: int = 1

    @property
    def runs(self) -> int:
        """Number of realizations (the leading axis)."""
        return self.swx.shape[0]

    def then(self, later: IdentificationMoments) -> IdentificationMoments:
        """Sums over this window followed by the adjacent window ``later`` (same realizations).

        Exact: the lag-1 pair that straddles the boundary is added from the edge vectors.
        """
        if self.n_samples == 0:
            return later
        if later.n_samples == 0:
            return self
        bridge = self.w_last[:, :, None] * later.w_first[:, None, :]
        return IdentificationMoments(
            swx=self.swx + later.swx,
            swe=self.swe + later.swe,
            s0=self.s0 + later.s0,
            s1=self.s1 + later.s1 + bridge,
            w_first=self.w_first,
            w_last=later.w_last,
            n_samples=self.n_samples + later.n_samples,
            t_start=self.t_start,
            t_stop=later.t_stop,
            records=self.records,
        )

    def total(self) -> IdentificationMoments:
        """Sums over every realization: one row, ``records`` = runs x records (the pooled estimate)."""
        return IdentificationMoments(
            swx=self.swx.sum(axis=0, keepdims=True),
            swe=self.swe.sum(axis=0, keepdims=True),
            s0=self.s0.sum(axis=0, keepdims=True),
            s1=self.s1.sum(axis=0, keepdims=True),
            w_first=self.w_first[:1] * np.nan,  # edges of a pooled sum do not chain
            w_last=self.w_last[:1] * np.nan,
            n_samples=self.n_samples,
            t_start=self.t_start,
            t_stop=self.t_stop,
            records=self.records * self.runs,
        )

    def add_records(self, other: IdentificationMoments) -> IdentificationMoments:
        """Pooled sums of two sets of realizations (same window): rows of ``total()`` added."""
        a, b = self.total(), other.total()
        return IdentificationMoments(
            swx=a.swx + b.swx,
            swe=a.swe + b.swe,
            s0=a.s0 + b.s0,
            s1=a.s1 + b.s1,
            w_first=a.w_first,
            w_last=a.w_last,
            n_samples=a.n_samples,
            t_start=a.t_start,
            t_stop=a.t_stop,
            records=a.records + b.records,
        )


def _rows(a: np.ndarray, idx: np.ndarray) -> np.ndarray:
    """``a[:, idx, :]`` as a view when ``idx`` is a contiguous range (no copy)."""
    if idx.size and np.array_equal(idx, np.arange(idx[0], idx[0] + idx.size)):
        return a[:, idx[0] : idx[0] + idx.size, :]
    return a[:, idx, :]


def _pairs(pairs: np.ndarray | None, q: int, r: int) -> list[tuple[int, int]]:
    if pairs is None:
        return [(c, ri) for c in range(q) for ri in range(r)]
    return [(int(c), int(ri)) for c, ri in np.asarray(pairs).reshape(-1, 2)]


def _dots(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``out[r, i, j] = sum_k a[r, i, k] b[r, j, k]`` (leading axes broadcast)."""
    return np.vecdot(a[:, :, None, :], b[:, None, :, :])


def compute_moments(
    z: np.ndarray,
    u: np.ndarray,
    e: np.ndarray,
    J: np.ndarray,
    L: np.ndarray,
    R: np.ndarray,
    ka: int,
    kb: int,
    times: tuple[float, float],
    swe_pairs: np.ndarray | None = None,
) -> IdentificationMoments:
    """The sums of :class:`IdentificationMoments` over sample indices ``ka <= k < kb``.

    Parameters
    ----------
    z : (runs, T, m) array
        Measurements (any strides; channel-major storage avoids copies).
    u : (T, p) or (runs, T, p) array
        Inputs.
    e : (runs, T - 1, m) array
        Chattering, ``e[:, k] = e(k+1|k)``.
    J, L, R : int arrays
        Measured channels used as regressors, input columns used as regressors, channels
        whose chattering is regressed.
    ka, kb : int
        Window of regressor indices, ``1 <= ka < kb <= T - 1``.
    times : (float, float)
        ``(t_start, t_stop)`` stored with the sums.
    swe_pairs : (P, 2) int array, optional
        The ``(regressor column, chattering row)`` pairs of ``Swe`` to compute (those of the
        estimated entries); the others are left 0. Default: all.
    """
    runs = z.shape[0]
    n = kb - ka
    zt = z.transpose(0, 2, 1)  # (runs, m, T) views
    et = e.transpose(0, 2, 1)
    zm1 = _rows(zt, J)[:, :, ka - 1 : kb - 1]  # z_J(k-1)
    z0 = _rows(zt, J)[:, :, ka:kb]  # z_J(k)
    er = _rows(et, R)[:, :, ka:kb]  # e_R(k+1)
    qj, pl = J.size, L.size
    # row-by-row dot products (np.vecdot: vectorized, ~3x faster than small batched matmuls); the
    # symmetric Gram once per pair, and of the chattering only the pairs some entry uses
    zz0 = np.empty((runs, qj, qj))
    for i in range(qj):
        for j in range(i, qj):
            zz0[:, i, j] = zz0[:, j, i] = np.vecdot(zm1[:, i], zm1[:, j])
    zz1 = _dots(zm1, z0)
    uL = u[..., L].swapaxes(-1, -2)  # (pl, T) or (runs, pl, T)
    if uL.ndim == 2:
        uL = uL[None]
    Uk, Uk1 = uL[:, :, ka:kb], uL[:, :, ka + 1 : kb]  # u(k), u(k+1)
    zu1 = _dots(zm1, Uk)  # sum z(k-1) u(k)'
    zu0 = _dots(z0, Uk)  # sum z(k) u(k)'
    zu2 = _dots(zm1[:, :, : n - 1], Uk1)  # sum_{k < kb-1} z(k-1) u(k+1)'
    r_ = er.shape[1]
    swe = np.zeros((runs, qj + pl, r_))
    for c, ri in _pairs(swe_pairs, qj + pl, r_):
        a = zm1[:, c] if c < qj else Uk[:, c - qj]
        swe[:, c, ri] = np.vecdot(a, er[:, ri])
    uu0 = np.broadcast_to(_dots(Uk, Uk), (runs, pl, pl))
    uu1 = np.broadcast_to(_dots(Uk[:, :, :-1], Uk1), (runs, pl, pl))
    u_first = np.broadcast_to(Uk[:, :, 0], (runs, pl))
    u_last = np.broadcast_to(Uk[:, :, -1], (runs, pl))
    q = qj + pl
    swx = np.empty((runs, q, q))
    s0 = np.empty((runs, q, q))
    s1 = np.empty((runs, q, q))
    swx[:, :qj, :qj], swx[:, :qj, qj:] = zz1, zu1
    swx[:, qj:, :qj], swx[:, qj:, qj:] = zu0.transpose(0, 2, 1), uu0
    s0[:, :qj, :qj], s0[:, :qj, qj:] = zz0, zu1
    s0[:, qj:, :qj], s0[:, qj:, qj:] = zu1.transpose(0, 2, 1), uu0
    # S1 pairs k, k+1 both inside [ka, kb): the k = kb - 1 term of zz1 and zu0 is not a pair
    z_prev_last, z_last = zm1[:, :, -1], z0[:, :, -1]
    s1[:, :qj, :qj] = zz1 - z_prev_last[:, :, None] * z_last[:, None, :]
    s1[:, :qj, qj:] = zu2
    s1[:, qj:, :qj] = zu0.transpose(0, 2, 1) - u_last[:, :, None] * z_last[:, None, :]
    s1[:, qj:, qj:] = uu1
    w_first = np.concatenate([zm1[:, :, 0], u_first], axis=1)
    w_last = np.concatenate([z_prev_last, u_last], axis=1)
    return IdentificationMoments(
        swx=swx,
        swe=swe,
        s0=s0,
        s1=s1,
        w_first=w_first,
        w_last=w_last,
        n_samples=n,
        t_start=float(times[0]),
        t_stop=float(times[1]),
    )


#: A measured regressor counts as excited when its energy exceeds the measurement noise's
#: expected energy by this many standard deviations of that energy (sqrt(2 N) r).
EXCITATION_SIGMAS = 10.0
#: Regressors of one channel whose scaled instrument matrix has a larger condition number
#: are collinear over the window: that channel's entries are not estimated.
MAX_CONDITION = 1e10


@dataclass(frozen=True, eq=False)
class IdentificationSetup:
    """The entries, regressors and hypotheses of identification on one model.

    Attributes
    ----------
    model : LinearModel
        Nominal model (full measurement).
    parameter_map : ParameterMap
        How the physical parameters enter A and B.
    hypotheses : tuple of Hypothesis
        The fault hypotheses tested (besides "no fault").
    rows, cols : (D,) int arrays
        Estimated entry a is the coefficient of regressor ``cols[a]`` (an index into
        ``x = [z_J, u_L]``) in the chattering of channel ``R[rows[a]]``.
    J, L, R : int arrays
        Measured channels used as regressors, input columns used as regressors, and the
        channels whose chattering carries a deviation.
    labels : tuple of str
        Entry names, ``"Phi[i,j]"`` / ``"G[i,l]"`` (1-based) in measurement coordinates
        (``A[i,j]`` / ``B[i,l]`` when C = I).
    """

    model: LinearModel
    parameter_map: ParameterMap
    hypotheses: tuple[Hypothesis, ...]
    rows: np.ndarray
    cols: np.ndarray
    J: np.ndarray
    L: np.ndarray
    R: np.ndarray
    labels: tuple[str, ...]
    # set by __post_init__
    _nominal_entries: np.ndarray = field(init=False, repr=False, compare=False)
    affine: tuple[bool, ...] = field(init=False, repr=False, compare=False)
    slopes: tuple[np.ndarray, ...] = field(init=False, repr=False, compare=False)
    _values: dict[str, object] = field(init=False, repr=False, compare=False)
    _plans: tuple[_DeviationPlan | None, ...] = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "_nominal_entries", self.parameter_map.evaluate(self.model.dt))
        object.__setattr__(self, "_values", self.parameter_map.values(self.model.dt))
        object.__setattr__(self, "_plans", tuple(self._plan(h) for h in range(len(self.hypotheses))))
        affine, slopes = [], []
        for h in range(len(self.hypotheses)):
            ok, G = self._affine(h)
            affine.append(ok)
            slopes.append(G)
        object.__setattr__(self, "affine", tuple(affine))
        object.__setattr__(self, "slopes", tuple(slopes))

    def _affine(self, h: int) -> tuple[bool, np.ndarray]:
        """Whether hypothesis ``h``'s entries are affine in its parameters, and their slopes ``(D, p)``.

        Checked at fixed probe points around the nominal values (up to 10 x their magnitude):
        affine maps are fitted in one exact step with these slopes.
        """
        theta0 = self.nominal(h)
        scale = np.where(theta0 == 0.0, 1.0, np.abs(theta0))
        G = self.jacobian(h, theta0, rel_step=1e-3)
        probes = np.random.default_rng(0).standard_normal((8, theta0.size)) * 3.0 * scale
        pred = probes @ G.T
        got = self.deviations(h, theta0 + probes)
        ref = np.maximum(np.abs(got).max(axis=0), 1e-300)
        return bool(np.all(np.abs(got - pred) <= 1e-8 * ref)), G

    @property
    def swe_pairs(self) -> np.ndarray:
        """``(D, 2)``: the (regressor column, chattering row) pair of each estimated entry."""
        return np.stack([self.cols, self.rows], axis=1)

    @property
    def n_entries(self) -> int:
        """Number of entries."""
        return int(self.rows.size)

    @property
    def channels(self) -> np.ndarray:
        """``(D,)``: the output channel of each estimated entry."""
        return self.R[self.rows]

    def nominal(self, h: int) -> np.ndarray:
        """Nominal values of hypothesis ``h``'s parameters."""
        return np.array([self._values[p] for p in self.hypotheses[h].parameters], dtype=float)

    def _plan(self, h: int) -> _DeviationPlan | None:
        """How :meth:`deviations` of hypothesis ``h`` reads the formulas directly (C = I), else None."""
        pm, model = self.parameter_map, self.model
        if not _identity(model.C):
            return None
        names = self.hypotheses[h].parameters
        # (matrix, row, col) -> entry index; a later declaration of a position wins, as in A and B
        where: dict[tuple[str, int, int], int] = {
            (e.matrix, e.row, e.col): k for k, e in enumerate(pm.entries)
        }
        depends = pm.depends(names)
        qj = self.J.size
        terms = []
        for a, (i, c) in enumerate(zip(self.R[self.rows], self.cols, strict=True)):
            key = ("A", int(i), int(self.J[c])) if c < qj else ("B", int(i), int(self.L[c - qj]))
            if key in where and depends[where[key]]:  # the other entries do not move: deviation exactly 0
                k = where[key]
                terms.append((a, k, float(self._nominal_entries[k])))
        return _DeviationPlan(pm, names, self._values, tuple(terms))

    def deviations(self, h: int, theta: np.ndarray) -> np.ndarray:
        """``(..., D)``: the entries' deviations when hypothesis ``h``'s parameters are ``theta (..., p)``."""
        pm, model = self.parameter_map, self.model
        names = self.hypotheses[h].parameters
        theta = np.asarray(theta, dtype=float)
        plan = self._plans[h]
        if plan is not None:
            return plan.deviations(theta, self.n_entries)
        dev = pm.evaluate(model.dt, {p: theta[..., i] for i, p in enumerate(names)}) - self._nominal_entries
        lead = dev.shape[:-1]
        n, p = model.n_states, model.n_inputs
        dA = np.zeros((*lead, n, n))
        dB = np.zeros((*lead, n, p))
        for k, e in enumerate(pm.entries):
            (dA if e.matrix == "A" else dB)[..., e.row, e.col] = dev[..., k]
        if not _identity(model.C):
            dA = model.C @ dA @ model.C_inv
            dB = model.C @ dB
        qj = self.J.size
        out = np.empty((*lead, self.n_entries))
        for a, (i, c) in enumerate(zip(self.R[self.rows], self.cols, strict=True)):
            out[..., a] = dA[..., i, self.J[c]] if c < qj else dB[..., i, self.L[c - qj]]
        return out

    def jacobian(self, h: int, theta: np.ndarray, rel_step: float = 1e-6) -> np.ndarray:
        """``(..., D, p)``: central differences of :meth:`deviations` (exact for quadratic formulas)."""
        return self.jacobian_deviations(h, theta, rel_step)[0]

    def jacobian_deviations(
        self, h: int, theta: np.ndarray, rel_step: float = 1e-6
    ) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`jacobian` and :meth:`deviations` at ``theta`` from one evaluation of the formulas on
        every shifted point at once (the same numbers as separate calls, with less overhead per call)."""
        theta = np.asarray(theta, dtype=float)
        scale = np.maximum(np.maximum(np.abs(theta), np.abs(self.nominal(h))), _tiny_scale(theta))
        p = theta.shape[-1]
        step = rel_step * scale  # parameter i shifted by step[..., i]
        steps = np.zeros((p, *theta.shape))
        for i in range(p):
            steps[i, ..., i] = step[..., i]
        dev = self.deviations(h, np.concatenate([theta + steps, theta - steps, theta[None]]))
        nd = step.ndim  # (np.moveaxis as transposes: a few us less per call)
        cols = (dev[:p] - dev[p : 2 * p]) / (2 * step).transpose(nd - 1, *range(nd - 1))[
            ..., None
        ]  # (p, ..., D)
        return np.ascontiguousarray(cols.transpose(*range(1, nd + 1), 0)), dev[2 * p]


@dataclass(frozen=True, eq=False)
class _DeviationPlan:
    """The formulas of the entries hypothesis ``names`` moves, for :meth:`IdentificationSetup.deviations`
    when C = I: each estimated entry is then one declared entry of A or B (or none)."""

    parameter_map: ParameterMap
    names: tuple[str, ...]
    values: dict[str, object]  # every name of the formulas at its nominal value (ParameterMap.values)
    terms: tuple[tuple[int, int, float], ...]  # (estimated entry, its declared entry, its nominal value)

    def deviations(self, theta: np.ndarray, n_entries: int) -> np.ndarray:
        vals = dict(self.values)
        vals.update({p: theta[..., i] for i, p in enumerate(self.names)})
        out = np.zeros((*theta.shape[:-1], n_entries))
        values = self.parameter_map.entry_values([k for _, k, _ in self.terms], vals)
        for (a, _, nominal), value in zip(self.terms, values, strict=True):
            out[..., a] = value - nominal
        return out


def _tiny_scale(theta: np.ndarray) -> np.ndarray:
    return np.where(theta == 0.0, 1.0, 0.0) + 1e-300


def _identity(C: np.ndarray) -> bool:
    return C.shape[0] == C.shape[1] and np.array_equal(C, np.eye(C.shape[0]))


def _measured_states(C: np.ndarray) -> set[int]:
    """States read directly by a row of C with a single nonzero entry."""
    out = set()
    for row in C:
        nz = np.flatnonzero(row)
        if nz.size == 1:
            out.add(int(nz[0]))
    return out


def _reduced_order_message(model: LinearModel, pm: ParameterMap | None) -> str:
    names = model.state_names
    measured = _measured_states(model.C)
    lines = []
    if pm is not None:
        for p in pm.parameter_names:
            ents = [e for e in pm.entries if p in e.formula.names]
            parts = []
            for e in ents:
                unmeasured = sorted(
                    {names[e.row]}
                    | ({names[e.col]} if e.matrix == "A" else set()) - {names[j] for j in measured}
                )
                parts.append(
                    e.label + (f" (involves unmeasured {', '.join(unmeasured)})" if unmeasured else "")
                )
            lines.append(f"{p}: {', '.join(parts)}")
    detail = ("; entries per parameter: " + "; ".join(lines)) if lines else ""
    return (
        f"{model.name!r}: identification needs every state measured (C square and invertible); C is "
        f"{model.n_outputs}x{model.n_states}. The chattering is then eq 23: the entries' deviations times "
        "the states C^-1 z(k) and the input. With fewer measurements (eq 24-28) a deviation multiplies "
        "unmeasured states and mixes with the reduced-order observer's terms d1(k-1), d2(k-1), so no "
        "parameter can be estimated by regression on the measurements; the spectral detector still "
        f"applies{detail}"
    )


def build_setup(
    model: Model, hypotheses: Sequence[Hypothesis | str | Sequence[str]] | None = None
) -> IdentificationSetup:
    """The :class:`IdentificationSetup` of ``model`` for ``hypotheses`` (default: the map's).

    The public entry point, documented there (parameters, errors), is
    :func:`chatterspec.detection.identification.identification_setup`.
    """
    if not is_linear(model):
        raise IdentifiabilityError(
            f"{getattr(model, 'name', 'the model')!r} is nonlinear: identification regresses the "
            "chattering of a linear model (eq 23) on its states and inputs"
        )
    pm = model.parameter_map
    if not model.full_measurement:
        raise IdentifiabilityError(_reduced_order_message(model, pm))
    if pm is None:
        raise IdentifiabilityError(
            f"{model.name!r} declares no physical parameters: give the model a parameter map "
            "(a model file's [parameters] and [entries] tables, see examples/README.md)"
        )
    pm.check(model)
    n_declared = len(pm.hypotheses)
    if hypotheses is not None:
        resolved: list[Hypothesis | str | Sequence[str]] = []
        declared = {d.name for d in pm.hypotheses}
        for given in hypotheses:
            resolved.append(pm.hypothesis(given) if isinstance(given, str) and given in declared else given)
        pm = pm.with_hypotheses(resolved)
        n_declared = len(pm.hypotheses)
    else:  # the declared hypotheses and every other combination (joint faults named without declaring them)
        pm = pm.with_hypotheses(pm.combinations())
    hyps = pm.hypotheses
    used = sorted({p for h in hyps for p in h.parameters})
    n, p = model.n_states, model.n_inputs
    mask_A, mask_B = np.zeros((n, n), bool), np.zeros((n, p), bool)
    for e, dep in zip(pm.entries, pm.depends(used), strict=True):
        if dep:
            (mask_A if e.matrix == "A" else mask_B)[e.row, e.col] = True
    C = model.C
    phi_mask = (np.abs(C) @ mask_A @ np.abs(model.C_inv)) > 0
    g_mask = (np.abs(C) @ mask_B) > 0
    R = np.flatnonzero(phi_mask.any(axis=1) | g_mask.any(axis=1))
    J = np.flatnonzero(phi_mask[R].any(axis=0))
    L = np.flatnonzero(g_mask[R].any(axis=0))
    rows, cols, labels = [], [], []
    eye = _identity(C)
    for ri, i in enumerate(R):
        for cj, j in enumerate(J):
            if phi_mask[i, j]:
                rows.append(ri)
                cols.append(cj)
                labels.append(f"{'A' if eye else 'Phi'}[{i + 1},{j + 1}]")
        for cl, l_ in enumerate(L):
            if g_mask[i, l_]:
                rows.append(ri)
                cols.append(J.size + cl)
                labels.append(f"{'B' if eye else 'G'}[{i + 1},{l_ + 1}]")
    setup = IdentificationSetup(
        model=model,
        parameter_map=pm,
        hypotheses=hyps,
        rows=np.array(rows, dtype=int),
        cols=np.array(cols, dtype=int),
        J=J,
        L=L,
        R=R,
        labels=tuple(labels),
    )
    keep = []
    for h, hyp in enumerate(hyps):
        G = setup.jacobian(h, setup.nominal(h))
        Gs = G / np.maximum(np.linalg.norm(G, axis=0), 1e-300)
        if np.linalg.matrix_rank(Gs, tol=1e-8) == len(hyp.parameters):
            keep.append(hyp)
        elif h < n_declared:
            raise IdentifiabilityError(
                f"hypothesis {hyp.name!r}: parameters {list(hyp.parameters)} change the entries "
                f"{', '.join(setup.labels)} only through fewer combinations than parameters; they "
                "cannot be told apart (declare them as separate hypotheses or fix one)"
            )
        # an added combination that cannot be told apart is not tested
    if len(keep) < len(hyps):
        return build_setup(model, keep)
    return setup


# --------------------------------------------------------------------------- the estimation
def _chi2_sf(x: np.ndarray, dof: np.ndarray) -> np.ndarray:
    """``scipy.stats.chi2.sf(x, dof)`` without importing :mod:`scipy.stats` (slow at start-up)."""
    return scipy.special.chdtrc(dof, x)


def _masked_inverse(A: np.ndarray, active: np.ndarray, eye: np.ndarray) -> np.ndarray:
    """Inverse of ``A`` with the inactive rows and columns replaced by the identity; a realization
    whose active block is exactly singular gets NaN (it fails the condition check)."""
    act2 = active[:, :, None] & active[:, None, :]
    M = np.where(act2, A, 0.0) + np.where(active, 0.0, 1.0)[:, :, None] * eye
    try:
        return np.linalg.inv(M)
    except np.linalg.LinAlgError:  # a singular realization fails the whole batch (exactly collinear data)
        sv = np.linalg.svd(M, compute_uv=False)
        singular = ~(sv[:, -1] > 1e-14 * sv[:, 0])
        out = np.linalg.inv(np.where(singular[:, None, None], eye, M))
        out[singular] = np.nan
        return out


def _gather(M: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``M[:, a[:, None], b[None, :]]``."""
    return M[:, a[:, None], b[None, :]]


def fit_moments(
    setup: IdentificationSetup, mom: IdentificationMoments, alpha: float, confidence: float
) -> dict[str, np.ndarray]:
    """Estimate entries, test and fit every hypothesis, select one: arrays with realizations leading.

    Returns a dict with ``entries (runs, D)``, ``entry_cov (runs, D, D)``, ``active (runs, D)``,
    ``no_fault_statistic/dof/p (runs,)``, ``theta (runs, H, P)``, ``se (runs, H, P)``,
    ``statistic/dof/p (runs, H)``, ``reason (runs, H)`` (int code, see :data:`REASONS`),
    ``selected (runs,)`` (hypothesis index, -1 = no fault, -2 = unexplained), ``entry_reason (runs, D)``.
    """
    model = setup.model
    runs, D, H = mom.runs, setup.n_entries, len(setup.hypotheses)
    qj = setup.J.size
    rows, cols, chans = setup.rows, setup.cols, setup.channels
    n = mom.n_samples * mom.records
    # --- excitation of each regressor, per realization
    diag0 = np.einsum("rii->ri", mom.s0)
    r_diag = np.concatenate([np.diag(model.R)[setup.J], np.zeros(setup.L.size)])
    # noise alone: sum of n squares of N(0, r) has mean n r and standard deviation sqrt(2 n) r
    excited = diag0 - n * r_diag > EXCITATION_SIGMAS * np.sqrt(2.0 * max(n, 1)) * r_diag
    excited &= diag0 > 0
    entry_reason = np.where(excited[:, cols], 0, 1)  # 1: regressor not excited
    # --- per-channel IV systems, block diagonal in one (D, D) matrix per realization
    same = rows[:, None] == rows[None, :]
    sc = np.sqrt(np.where(diag0 > 0, diag0, 1.0))[:, cols]  # (runs, D)
    A = np.where(same, _gather(mom.swx, cols, cols), 0.0) / (sc[:, :, None] * sc[:, None, :])
    b = mom.swe[:, cols, rows] / sc
    eye = np.eye(D)
    active = entry_reason == 0
    Ainv = _masked_inverse(A, active, eye)
    # collinear regressors of a channel: 1-norm condition number of its block (A and its inverse at hand)
    for ri in range(setup.R.size):
        blk = np.flatnonzero(rows == ri)
        sub_a = np.abs(A[:, blk[:, None], blk[None, :]] * active[:, blk, None] * active[:, None, blk])
        sub_i = np.abs(Ainv[:, blk[:, None], blk[None, :]])
        with np.errstate(invalid="ignore", over="ignore"):
            cond = sub_a.sum(axis=1).max(axis=1) * sub_i.sum(axis=1).max(axis=1)
        bad = ~(cond < MAX_CONDITION) & active[:, blk].any(axis=1)
        entry_reason[:, blk] = np.where(bad[:, None] & active[:, blk], 2, entry_reason[:, blk])
    if np.any(entry_reason != (~active).astype(int)):  # some block was dropped: invert again without it
        active = entry_reason == 0
        Ainv = _masked_inverse(A, active, eye)
    act2 = active[:, :, None] & active[:, None, :]
    b = np.where(active, b, 0.0)
    d = np.einsum("rab,rb->ra", Ainv, b) / sc
    # --- covariance: lag-1 sandwich with the MA(1) autocovariances at the fitted true plant
    Phi_t = np.broadcast_to(model.C @ model.A @ model.C_inv, (runs, *model.A.shape)).copy()
    zc = cols < qj
    idx = (slice(None), setup.R[rows[zc]], setup.J[cols[zc]])
    np.add.at(Phi_t, idx, d[:, zc])  # type: ignore[arg-type]  # numpy's stubs: no tuple index (ufunc.at takes one)
    Rm = model.R
    CQC = model.C @ model.Q @ model.C.T
    G0 = CQC + Rm + Phi_t @ Rm @ Phi_t.transpose(0, 2, 1)
    G1 = -(Rm @ Phi_t.transpose(0, 2, 1))  # E[eta(k) eta(k+1)']
    S0 = _gather(mom.s0, cols, cols)
    S1 = _gather(mom.s1, cols, cols)
    Om = (
        _gather(G0, chans, chans) * S0
        + _gather(G1, chans, chans) * S1
        + _gather(G1, chans, chans).transpose(0, 2, 1) * S1.transpose(0, 2, 1)
    ) / (sc[:, :, None] * sc[:, None, :])
    Om = np.where(act2, Om, 0.0)
    V = Ainv @ Om @ Ainv.transpose(0, 2, 1) / (sc[:, :, None] * sc[:, None, :])
    se_e = np.sqrt(np.clip(np.einsum("raa->ra", V), 0.0, None))
    T = np.where(active & (se_e > 0), se_e, 1.0)
    Vn = (
        np.where(act2, V / (T[:, :, None] * T[:, None, :]), 0.0)
        + np.where(active, 0.0, 1.0)[:, :, None] * eye
    )
    lam, Q = np.linalg.eigh(Vn)
    keep = lam > 1e-10 * lam[:, -1:]
    W = np.where(keep, 1.0 / np.sqrt(np.where(keep, lam, 1.0)), 0.0)[:, :, None] * Q.transpose(0, 2, 1)
    n_dirs = keep.sum(axis=1) - (~active).sum(axis=1)
    dn = np.where(active, d / T, 0.0)
    wd = np.einsum("rab,rb->ra", W, dn)
    stat0 = (wd**2).sum(axis=1)
    p0 = np.where(n_dirs > 0, _chi2_sf(stat0, np.maximum(n_dirs, 1)), 1.0)
    # --- each hypothesis: minimum-distance fit of its parameters to the entries
    P = max(len(h.parameters) for h in setup.hypotheses)
    theta = np.full((runs, H, P), np.nan)
    se = np.full((runs, H, P), np.nan)
    stat = np.full((runs, H), np.nan)
    dof = np.zeros((runs, H), dtype=int)
    reason = np.zeros((runs, H), dtype=int)
    for h, hyp in enumerate(setup.hypotheses):
        th, cov, J, ok, why = _fit_hypothesis(setup, h, dn, W, T, active)
        k = len(hyp.parameters)
        theta[:, h, :k] = np.where(ok[:, None], th, np.nan)
        se[:, h, :k] = np.where(ok[:, None], np.sqrt(np.clip(np.einsum("rii->ri", cov), 0.0, None)), np.nan)
        stat[:, h] = np.where(ok, J, np.nan)
        dof[:, h] = n_dirs - k
        touched = np.any(setup.slopes[h] != 0, axis=1)  # the entries the hypothesis moves
        collinear = np.any((entry_reason == 2) & touched, axis=1)
        reason[:, h] = np.where((why == 1) & collinear, 3, why)
    p = np.where(dof > 0, _chi2_sf(stat, np.maximum(dof, 1)), np.where(np.isfinite(stat), 1.0, np.nan))
    selected = _select(setup, p0, p, alpha)
    return {
        "entries": np.where(active, d, np.nan),
        "entry_cov": V,
        "active": active,
        "entry_reason": entry_reason,
        "no_fault_statistic": stat0,
        "no_fault_dof": n_dirs,
        "no_fault_p": p0,
        "theta": theta,
        "se": se,
        "statistic": stat,
        "dof": dof,
        "p": p,
        "reason": reason,
        "selected": selected,
    }


#: Reason codes of a missing estimate (``fit_moments`` ``reason``).
REASONS = {
    0: "",
    1: "not identifiable on this window: the regressors of the entries it enters carry no excitation",
    2: "the fit did not converge",
    3: "not identifiable on this window: the regressors of the entries it enters are collinear",
    4: "not identifiable on this window: its parameters move the entries alike (their effects cannot be told "
    "apart)",
}


def _separable(N: np.ndarray, ok: np.ndarray) -> np.ndarray:
    """Which realizations' normal matrices ``N`` (unit diagonal, ``(runs, p, p)``) are of full rank.

    Two parameters whose whitened Jacobian columns are parallel leave ``N`` singular: their sum is
    identified, each one is not. ``ok`` rows already refused are passed through unchanged (True).
    """
    if N.shape[-1] < 2:
        return np.ones(N.shape[0], dtype=bool)
    lam = np.linalg.eigvalsh(np.where(ok[:, None, None], N, np.eye(N.shape[-1])))
    return lam[:, 0] > 1e-10 * lam[:, -1]


def _column_norms(x: np.ndarray) -> np.ndarray:
    """``np.linalg.norm(x, axis=1)`` of a real array, the same operations without its checks (the
    Gauss-Newton loop takes it twice per iteration, on a handful of realizations at the end)."""
    return np.sqrt(np.add.reduce(x * x, axis=1))


def _fit_hypothesis(
    setup: IdentificationSetup, h: int, dn: np.ndarray, W: np.ndarray, T: np.ndarray, active: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Gauss-Newton on the whitened residual ``W (d - g(theta)) / T``, every realization at once
    (one exact step when the hypothesis is affine in its parameters)."""
    runs = dn.shape[0]
    theta0 = setup.nominal(h)
    if setup.affine[h]:
        G = np.where(active[:, :, None], setup.slopes[h][None] / T[:, :, None], 0.0)
        Gt = np.einsum("rab,rbk->rak", W, G)
        r0 = np.einsum("rab,rb->ra", W, dn)
        cn = np.linalg.norm(Gt, axis=1)
        # a parameter whose entries are all inactive (no excitation) has a zero whitened column
        ok = np.all(cn > 1e-12 * np.maximum(np.linalg.norm(G, axis=1), 1e-300), axis=1)
        cs = np.where(cn > 0, cn, 1.0)
        Gs = Gt / cs[:, None, :]
        N = Gs.transpose(0, 2, 1) @ Gs
        apart = _separable(N, ok)
        why = np.where(ok, np.where(apart, 0, 4), 1)
        ok = ok & apart
        N = N + np.where(ok, 0.0, 1.0)[:, None, None] * np.eye(theta0.size)
        Ninv = np.linalg.inv(N)
        step = np.einsum("rkl,ral,ra->rk", Ninv, Gs, r0) / cs
        step = np.where(ok[:, None], step, 0.0)
        res = r0 - np.einsum("rak,rk->ra", Gt, step)
        cov = Ninv / (cs[:, :, None] * cs[:, None, :])
        return theta0 + step, cov, (res**2).sum(axis=1), ok, why
    theta = np.broadcast_to(theta0, (runs, theta0.size)).copy()
    scale = np.maximum(np.abs(theta0), 1.0 * (theta0 == 0))
    ok = np.ones(runs, dtype=bool)
    why = np.zeros(runs, dtype=int)
    # each realization iterates until its own step is below the tolerance (then it is left alone), so
    # its result does not depend on the others in the batch (a stream cut into other pushes); the live
    # realizations' rows are kept apart and written back as each one is done
    step = np.zeros_like(theta)
    eye = np.eye(theta.shape[1])
    live = np.arange(runs)
    th, st, okl, whyl = theta[live], step[live], ok[live], why[live]
    Wl, Tl, al, dnl = W[live], T[live], active[live], dn[live]
    for _ in range(60):
        G, g = setup.jacobian_deviations(h, th)  # (live, D, p), (live, D)
        r = np.einsum("rab,rb->ra", Wl, dnl - np.where(al, g / Tl, 0.0))
        GT = G / Tl[:, :, None]
        Gt = np.einsum("rab,rbk->rak", Wl, np.where(al[:, :, None], GT, 0.0))
        cn = _column_norms(Gt)  # (live, p)
        lost_any = (~(cn > 1e-12 * np.maximum(_column_norms(GT), 1e-300))).any(axis=1)
        whyl = np.where(lost_any & okl, 1, whyl)
        okl = okl & ~lost_any
        cn = np.where(cn > 0, cn, 1.0)
        Gs = Gt / cn[:, None, :]
        N = Gs.transpose(0, 2, 1) @ Gs
        apart = _separable(N, okl)
        whyl = np.where(~apart & okl, 4, whyl)
        okl = okl & apart
        N = N + np.where(okl, 0.0, 1.0)[:, None, None] * eye
        st = np.linalg.solve(N, np.einsum("rak,ra->rk", Gs, r)[..., None])[..., 0] / cn
        st = np.where(okl[:, None], st, 0.0)
        th = th + st
        done = np.all(np.abs(st) <= 1e-10 * (np.abs(th) + 1e-6 * scale), axis=1)
        if done.any():
            fin, keep = live[done], ~done
            theta[fin], step[fin], ok[fin], why[fin] = th[done], st[done], okl[done], whyl[done]
            live, th, st, okl, whyl = live[keep], th[keep], st[keep], okl[keep], whyl[keep]
            if live.size == 0:
                break
            Wl, Tl, al, dnl = Wl[keep], Tl[keep], al[keep], dnl[keep]
    else:
        theta[live], step[live], ok[live], why[live] = th, st, okl, whyl
        bad = np.zeros(runs, dtype=bool)
        bad[live] = np.any(np.abs(step[live]) > 1e-6 * (np.abs(theta[live]) + 1e-6 * scale), axis=1)
        why = np.where(bad & ok, 2, why)
        ok &= ~bad
    G, g = setup.jacobian_deviations(h, theta)
    r = np.einsum("rab,rb->ra", W, dn - np.where(active, g / T, 0.0))
    Gt = np.einsum("rab,rbk->rak", W, np.where(active[:, :, None], G / T[:, :, None], 0.0))
    N = Gt.transpose(0, 2, 1) @ Gt + np.where(ok, 0.0, 1.0)[:, None, None] * np.eye(theta.shape[1])
    cov = np.linalg.inv(N)
    finite = np.all(np.isfinite(theta), axis=1)
    why = np.where(ok & ~finite, 2, why)
    ok &= finite
    return theta, cov, (r**2).sum(axis=1), ok, why


def _select(setup: IdentificationSetup, p0: np.ndarray, p: np.ndarray, alpha: float) -> np.ndarray:
    """-1 (no fault) unless its test rejects at ``alpha``; else the fewest-parameter hypothesis not
    rejected at ``alpha`` (ties: largest p-value); -2 (unexplained) if every hypothesis is rejected."""
    sizes = np.array([len(h.parameters) for h in setup.hypotheses])
    fits = np.nan_to_num(p, nan=-1.0) > alpha
    # rank: fewer parameters first, then larger p-value
    key = np.where(fits, -sizes[None, :] * 10.0 + np.nan_to_num(p, nan=0.0), -np.inf)
    best = np.argmax(key, axis=1)
    chosen = np.where(fits.any(axis=1), best, -2)
    return np.where(p0 > alpha, -1, chosen)


def selection_names(setup: IdentificationSetup, selected: np.ndarray) -> list[str]:
    """Hypothesis names of selection indices (-1 no fault, -2 unexplained)."""
    names = [h.name for h in setup.hypotheses]
    return [
        NO_FAULT if s == -1 else UNEXPLAINED if s == -2 else names[s] for s in np.asarray(selected).ravel()
    ]


def true_parameters(setup: IdentificationSetup, true_model: LinearModel) -> dict[str, np.ndarray]:
    """Each hypothesis's parameters fitted to ``true_model``'s exact A and B (no noise).

    Parameters
    ----------
    setup : IdentificationSetup
        The nominal model's entries and hypotheses (:func:`identification_setup`).
    true_model : LinearModel
        The true plant, with the nominal model's shapes.

    Returns ``{hypothesis: theta}``; the hypothesis whose fit reproduces the true entries
    (relative misfit below 1e-9) explains the true plant (see :func:`true_hypothesis`).
    """
    out = {}
    for h, hyp in enumerate(setup.hypotheses):
        out[hyp.name] = _exact_fit(setup, h, true_model)[0]
    return out


def _true_deviation(setup: IdentificationSetup, true_model: LinearModel) -> np.ndarray:
    m = setup.model
    dPhi = true_model.C @ true_model.A @ true_model.C_inv - m.C @ m.A @ m.C_inv
    dG = true_model.C @ true_model.B - m.C @ m.B
    qj = setup.J.size
    return np.array(
        [
            dPhi[setup.R[i], setup.J[c]] if c < qj else dG[setup.R[i], setup.L[c - qj]]
            for i, c in zip(setup.rows, setup.cols, strict=True)
        ]
    )


def _entry_scale(setup: IdentificationSetup) -> np.ndarray:
    """Magnitude of each estimated entry's row in the nominal [C A C^-1, C B] (a scale for fits)."""
    m = setup.model
    full = np.abs(np.concatenate([m.C @ m.A @ m.C_inv, m.C @ m.B], axis=1))
    return np.maximum(full[setup.R[setup.rows]].max(axis=1), 1e-300)


def _exact_fit(setup: IdentificationSetup, h: int, true_model: LinearModel) -> tuple[np.ndarray, float]:
    target = _true_deviation(setup, true_model)
    scale = _entry_scale(setup)
    theta = setup.nominal(h).astype(float)
    for _ in range(100):
        G = setup.jacobian(h, theta) / scale[:, None]
        r = (target - setup.deviations(h, theta)) / scale
        step, *_ = np.linalg.lstsq(G, r, rcond=None)
        theta = theta + step
        if np.all(np.abs(step) <= 1e-13 * (np.abs(theta) + 1e-300)):
            break
    r = (target - setup.deviations(h, theta)) / scale
    return theta, float(np.sqrt(np.mean(r**2))) if r.size else 0.0


def true_hypothesis(setup: IdentificationSetup, true_model: LinearModel) -> str | None:
    """Name of the hypothesis that reproduces ``true_model`` (fewest parameters), ``"no fault"``
    when the estimated entries do not deviate, None when no declared hypothesis explains it
    (``setup`` and ``true_model`` as in :func:`true_parameters`)."""
    target = _true_deviation(setup, true_model)
    if np.all(np.abs(target) <= 1e-12 * _entry_scale(setup)):
        return NO_FAULT
    fits = []
    for h, hyp in enumerate(setup.hypotheses):
        _, misfit = _exact_fit(setup, h, true_model)
        if misfit < 1e-9:
            fits.append((len(hyp.parameters), hyp.name))
    return min(fits)[1] if fits else None


def check_alpha(alpha: float, confidence: float) -> tuple[float, float]:
    """``(alpha, confidence)`` as floats, each checked to lie in (0, 1)."""
    for name, v in (("alpha", alpha), ("confidence", confidence)):
        if not 0.0 < float(v) < 1.0:
            raise ParameterError(f"{name} must lie in (0, 1); got {v!r}")
    return float(alpha), float(confidence)


#: Method name reported with every result.
METHOD = "instrumental variables (z(k-1)), lag-1 sandwich covariance, minimum-distance hypotheses"


@dataclass(frozen=True)
class ParameterEstimate:
    """One parameter of one hypothesis: the plant's value with its interval.

    Attributes
    ----------
    hypothesis, parameter : str
    estimate : float
        The plant's value (nominal + estimated deviation), in ``unit``; NaN without an estimate.
    ci_low, ci_high : float
        Delta-method Wald interval at ``confidence``.
    std_error : float
    unit : str
    nominal : float
        The nominal model's value.
    confidence : float
    reason : str
        Why there is no estimate (empty when there is one).
    """

    hypothesis: str
    parameter: str
    estimate: float
    ci_low: float
    ci_high: float
    std_error: float
    unit: str
    nominal: float
    confidence: float
    reason: str = ""

    def __repr__(self) -> str:
        if not np.isfinite(self.estimate):
            return f"ParameterEstimate({self.parameter}: no estimate, {self.reason})"
        u, se = (f" {self.unit}" if self.unit else ""), self.std_error
        lo, hi = format_with_error(self.ci_low, se), format_with_error(self.ci_high, se)
        return (
            f"ParameterEstimate({self.parameter} = {format_with_error(self.estimate, se)}{u}, "
            f"{self.confidence:.0%} [{lo}, {hi}])"
        )


@dataclass(frozen=True)
class HypothesisTest:
    """The test of one hypothesis: minimum distance (or the Wald statistic for "no fault").

    Attributes
    ----------
    hypothesis : str
    parameters : tuple of str
    statistic : float
        Chi-squared statistic (NaN when the hypothesis could not be fitted).
    dof : int
    p_value : float
    fits : bool
        Not rejected at ``alpha`` (``p_value > alpha``).
    """

    hypothesis: str
    parameters: tuple[str, ...]
    statistic: float
    dof: int
    p_value: float
    fits: bool


def _sig(x: float, se: float) -> int:
    """Significant digits that keep two of the standard error."""
    if not (np.isfinite(x) and np.isfinite(se)) or x == 0 or se <= 0:
        return 6
    return int(min(12, max(2, np.floor(np.log10(abs(x))) - np.floor(np.log10(se)) + 2)))


def format_with_error(x: float, se: float) -> str:
    """``x`` as text with the digits that keep two of the standard error ``se`` (trailing zeros kept).

    Parameters
    ----------
    x : float
        The value (any unit; ``"nan"`` when not finite).
    se : float
        Its standard error, same unit.
    """
    if not np.isfinite(x):
        return "nan"
    text = f"{x:#.{_sig(x, se)}g}"
    mant, _, exp = text.partition("e")
    return mant.rstrip(".") + (f"e{exp}" if exp else "")


def _round(x: float, se: float) -> float | None:
    return None if not np.isfinite(x) else float(f"{x:.{_sig(x, se)}g}")


def _round_stat(x: float) -> float | None:
    return None if not np.isfinite(x) else float(f"{x:.4g}")


@dataclass(frozen=True)
class IdentificationReport:
    """Identification of one record (or of many records pooled): estimates, tests, selection.

    Attributes
    ----------
    selected : str
        The selected hypothesis, ``"no fault"`` or ``"unexplained"``.
    estimates : tuple of ParameterEstimate
        One per (hypothesis, parameter), in hypothesis order.
    tests : tuple of HypothesisTest
        ``"no fault"`` first, then one per hypothesis.
    window_s : (float, float)
        Times (s) of the first and one past the last chattering sample used.
    n_samples : int
        Chattering samples per record.
    records : int
        Records pooled (1 for a single record).
    alpha, confidence : float
    entries : tuple of (str, float, float)
        Estimated matrix entries' deviations ``(label, estimate, std_error)``.
    selection_rate : dict or None
        Fraction of single records selecting each hypothesis (pooled reports of many runs).
    """

    selected: str
    estimates: tuple[ParameterEstimate, ...]
    tests: tuple[HypothesisTest, ...]
    window_s: tuple[float, float]
    n_samples: int
    records: int
    alpha: float
    confidence: float
    entries: tuple[tuple[str, float, float], ...] = ()
    selection_rate: dict[str, float] | None = None

    def estimate(self, hypothesis: str | None = None) -> tuple[ParameterEstimate, ...]:
        """The estimates of ``hypothesis`` (default: the selected one; empty for no fault)."""
        name = self.selected if hypothesis is None else hypothesis
        return tuple(e for e in self.estimates if e.hypothesis == name)

    def __repr__(self) -> str:
        sel = self.estimate()
        what = ", ".join(
            f"{e.parameter} = {format_with_error(e.estimate, e.std_error)} "
            f"[{format_with_error(e.ci_low, e.std_error)}, "
            f"{format_with_error(e.ci_high, e.std_error)}]{(' ' + e.unit) if e.unit else ''}"
            for e in sel
        )
        return f"IdentificationReport(selected={self.selected!r}{', ' + what if what else ''})"

    def to_dict(self) -> dict[str, object]:
        """JSON-ready: ``selected``, ``hypotheses`` (one entry per hypothesis and parameter with
        ``hypothesis``, ``parameter``, ``estimate``, ``ci_low``, ``ci_high``, ``unit``, ``nominal``,
        ``std_error``, ``statistic``, ``dof``, ``p_value``, ``fits``, ``reason``; "no fault" first with
        ``parameter`` null), ``window_s``, ``n_samples``, ``records``, ``alpha``, ``confidence``,
        ``method``, ``entries`` and, for pooled runs, ``selection_rate``. Estimates keep two
        significant digits of their standard error; statistics four digits."""
        tests = {t.hypothesis: t for t in self.tests}
        rows: list[dict[str, object]] = []
        t0 = tests[NO_FAULT]
        rows.append(
            {
                "hypothesis": NO_FAULT,
                "parameter": None,
                "estimate": None,
                "ci_low": None,
                "ci_high": None,
                "unit": None,
                "statistic": _round_stat(t0.statistic),
                "dof": t0.dof,
                "p_value": _round_stat(t0.p_value),
                "fits": bool(t0.fits),
            }
        )
        for e in self.estimates:
            t = tests[e.hypothesis]
            rows.append(
                {
                    "hypothesis": e.hypothesis,
                    "parameter": e.parameter,
                    "estimate": _round(e.estimate, e.std_error),
                    "ci_low": _round(e.ci_low, e.std_error),
                    "ci_high": _round(e.ci_high, e.std_error),
                    "unit": e.unit,
                    "nominal": e.nominal,
                    "std_error": _round_stat(e.std_error),
                    "statistic": _round_stat(t.statistic),
                    "dof": t.dof,
                    "p_value": _round_stat(t.p_value),
                    "fits": bool(t.fits),
                    **({"reason": e.reason} if e.reason else {}),
                }
            )
        out: dict[str, object] = {
            "selected": self.selected,
            "hypotheses": rows,
            "window_s": [round(self.window_s[0], 9), round(self.window_s[1], 9)],
            "n_samples": self.n_samples,
            "records": self.records,
            "alpha": self.alpha,
            "confidence": self.confidence,
            "method": METHOD,
            "entries": [
                {"entry": lab, "deviation": _round(v, s), "std_error": _round_stat(s)}
                for lab, v, s in self.entries
            ],
        }
        if self.selection_rate is not None:
            out["selection_rate"] = {k: round(v, 6) for k, v in self.selection_rate.items()}
        return out

    def table(self) -> str:
        """A plain-text table: one row per hypothesis and parameter, "no fault" first."""
        pct = f"{self.confidence:.0%}"
        head = (
            f"{'hypothesis':<18} {'parameter':<18} {'estimate':>12} {pct + ' interval':>27} {'unit':<11} "
            f"{'nominal':>10} {'statistic':>10} {'dof':>4} {'p-value':>9}"
        )
        lines = [head]
        tests = {t.hypothesis: t for t in self.tests}

        def mark(name: str) -> str:
            return "  <- selected" if name == self.selected else ""

        t0 = tests[NO_FAULT]
        lines.append(
            f"{NO_FAULT:<18} {'-':<18} {'-':>12} {'-':>27} {'-':<11} {'-':>10} {t0.statistic:10.4g} "
            f"{t0.dof:4d} {t0.p_value:9.3g}{mark(NO_FAULT)}"
        )
        for e in self.estimates:
            t = tests[e.hypothesis]
            if np.isfinite(e.estimate):
                est = format_with_error(e.estimate, e.std_error)
                lo, hi = format_with_error(e.ci_low, e.std_error), format_with_error(e.ci_high, e.std_error)
                ci = f"[{lo}, {hi}]"
            else:
                est, ci = "none", "-"
            lines.append(
                f"{e.hypothesis:<18} {e.parameter:<18} {est:>12} {ci:>27} {e.unit:<11} {e.nominal:10.4g} "
                f"{t.statistic:10.4g} {t.dof:4d} {t.p_value:9.3g}{mark(e.hypothesis)}"
            )
            if e.reason:
                lines.append(f"{'':<18} ({e.reason})")
        lines.append(f"selected: {self.selected}")
        if self.selected == UNEXPLAINED:
            lines.append(
                "(every declared hypothesis is rejected: a fault outside the declared ones, or several)"
            )
        return "\n".join(lines)


@dataclass(frozen=True, eq=False)
class Identification:
    """Identification of many realizations at once (arrays with realizations leading).

    Attributes
    ----------
    setup : IdentificationSetup
    moments : IdentificationMoments
        The sums it was computed from (``moments.total()`` gives the pooled estimate).
    alpha, confidence : float
    fit : dict of arrays
        ``theta (runs, H, P)`` (plant's values), ``se``, ``statistic (runs, H)``, ``dof``, ``p``,
        ``no_fault_statistic (runs,)``, ``no_fault_dof``, ``no_fault_p``, ``selected (runs,)``
        (-1 no fault, -2 unexplained, else the hypothesis index), ``entries (runs, D)``,
        ``entry_cov``, ``active``, ``reason``.
    """

    setup: IdentificationSetup
    moments: IdentificationMoments
    alpha: float
    confidence: float
    fit: dict[str, np.ndarray]

    @property
    def runs(self) -> int:
        """Number of realizations (the leading axis)."""
        return self.moments.runs

    def take(self, rows: slice) -> Identification:
        """The realizations ``rows`` (each realization's fit is its own: see
        :meth:`OnlineIdentifier.share`)."""
        fit = {k: v[rows] for k, v in self.fit.items()}
        return Identification(self.setup, _take(self.moments, rows), self.alpha, self.confidence, fit)

    @property
    def hypothesis_names(self) -> tuple[str, ...]:
        """Names of the tested hypotheses, in the setup's order."""
        return tuple(h.name for h in self.setup.hypotheses)

    @property
    def selected(self) -> list[str]:
        """Selected hypothesis name per realization."""
        return selection_names(self.setup, self.fit["selected"])

    def selection_rate(self) -> dict[str, float]:
        """Fraction of realizations selecting each name ("no fault", hypotheses, "unexplained")."""
        sel = self.fit["selected"]
        names = {NO_FAULT: -1, **{n: i for i, n in enumerate(self.hypothesis_names)}, UNEXPLAINED: -2}
        return {n: float(np.mean(sel == i)) for n, i in names.items()}

    def _index(self, hypothesis: str, parameter: str | None) -> tuple[int, int]:
        names = self.hypothesis_names
        if hypothesis not in names:
            raise ParameterError(f"no hypothesis {hypothesis!r}; tested: {', '.join(names)}")
        h = names.index(hypothesis)
        params = self.setup.hypotheses[h].parameters
        parameter = params[0] if parameter is None else parameter
        if parameter not in params:
            raise ParameterError(f"hypothesis {hypothesis!r} has parameters {params}; not {parameter!r}")
        return h, params.index(parameter)

    def estimate(self, hypothesis: str, parameter: str | None = None) -> np.ndarray:
        """``(runs,)`` plant's value of ``parameter`` under ``hypothesis`` (NaN where not estimated)."""
        h, i = self._index(hypothesis, parameter)
        return self.fit["theta"][:, h, i]

    def interval(self, hypothesis: str, parameter: str | None = None) -> tuple[np.ndarray, np.ndarray]:
        """``(low, high)`` arrays of the Wald interval at ``confidence``."""
        h, i = self._index(hypothesis, parameter)
        zq = scipy.special.ndtri(0.5 + self.confidence / 2)  # normal quantile
        th, se = self.fit["theta"][:, h, i], self.fit["se"][:, h, i]
        return th - zq * se, th + zq * se

    def report(self, run: int = 0, *, selection_rate: dict[str, float] | None = None) -> IdentificationReport:
        """The :class:`IdentificationReport` of realization ``run``."""
        f, s = self.fit, self.setup
        zq = scipy.special.ndtri(0.5 + self.confidence / 2)  # normal quantile
        pm = s.parameter_map
        estimates, tests = [], []
        tests.append(
            HypothesisTest(
                NO_FAULT,
                (),
                float(f["no_fault_statistic"][run]),
                int(f["no_fault_dof"][run]),
                float(f["no_fault_p"][run]),
                bool(f["no_fault_p"][run] > self.alpha),
            )
        )
        for h, hyp in enumerate(s.hypotheses):
            p = float(f["p"][run, h])
            tests.append(
                HypothesisTest(
                    hyp.name,
                    hyp.parameters,
                    float(f["statistic"][run, h]),
                    int(f["dof"][run, h]),
                    p,
                    bool(p > self.alpha),
                )
            )
            for i, name in enumerate(hyp.parameters):
                th, se = float(f["theta"][run, h, i]), float(f["se"][run, h, i])
                par = pm.parameter(name)
                estimates.append(
                    ParameterEstimate(
                        hypothesis=hyp.name,
                        parameter=name,
                        estimate=th,
                        ci_low=th - zq * se,
                        ci_high=th + zq * se,
                        std_error=se,
                        unit=par.unit,
                        nominal=par.value,
                        confidence=self.confidence,
                        reason=REASONS[int(f["reason"][run, h])] if not np.isfinite(th) else "",
                    )
                )
        entries = tuple(
            (lab, float(f["entries"][run, a]), float(np.sqrt(max(f["entry_cov"][run, a, a], 0.0))))
            for a, lab in enumerate(s.labels)
        )
        mom = self.moments
        return IdentificationReport(
            selected=selection_names(s, f["selected"][run : run + 1])[0],
            estimates=tuple(estimates),
            tests=tuple(tests),
            window_s=(mom.t_start, mom.t_stop),
            n_samples=mom.n_samples,
            records=mom.records,
            alpha=self.alpha,
            confidence=self.confidence,
            entries=entries,
            selection_rate=selection_rate,
        )


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


@dataclass(frozen=True, eq=False)
class OnlineIdentification:
    """The windows one push completed.

    Attributes
    ----------
    frames : (F,) int array
        Window (hop) numbers, the monitor's frame numbers.
    times_s : (F,) array
        Centre time (s) of each window.
    window_s : (F, 2) array
        First and one-past-last chattering time (s) of each window.
    result : Identification or None
        One realization per window (``result.report(i)`` for window i); None when F = 0.
    """

    frames: np.ndarray
    times_s: np.ndarray
    window_s: np.ndarray
    result: Identification | None

    @property
    def n_windows(self) -> int:
        """Number of identification windows."""
        return int(self.frames.size)

    def take(self, windows: slice) -> OnlineIdentification:
        """The windows ``windows`` (none: no result)."""
        frames = self.frames[windows]
        result = None if self.result is None or frames.size == 0 else self.result.take(windows)
        return OnlineIdentification(frames, self.times_s[windows], self.window_s[windows], result)

    def report(self, i: int) -> IdentificationReport:
        """The :class:`~chatterspec.detection.identification.IdentificationReport` of window ``i``."""
        if self.result is None:
            raise IndexError("this push completed no window")
        rep = self.result.report(i)
        return dataclasses.replace(rep, window_s=(float(self.window_s[i, 0]), float(self.window_s[i, 1])))


_FIELDS = ("swx", "swe", "s0", "s1")


class OnlineIdentifier:
    """Identification per hop over a sliding window of the raw stream.

    Parameters
    ----------
    setup : IdentificationSetup
        From :func:`chatterspec.detection.identification.identification_setup`.
    hop_samples : int
        Samples per hop (the monitor's ``n_hop``).
    window_hops : int
        Hops per window (default 5: the monitor's 1 s window at a 0.2 s hop).
    t0 : float
        Time (s) of the first measurement pushed.
    alpha, confidence : float
        Test level and interval level (see :func:`~chatterspec.detection.identification.identify_moments`).
    """

    def __init__(
        self,
        setup: IdentificationSetup,
        *,
        hop_samples: int,
        window_hops: int = 5,
        t0: float = 0.0,
        alpha: float = 1e-3,
        confidence: float = 0.95,
    ) -> None:
        self.setup = setup
        self.H = positive_int("hop_samples", hop_samples)
        self.n = positive_int("window_hops", window_hops)
        self.alpha, self.confidence = alpha, confidence
        self.dt = setup.model.dt
        model = setup.model
        self._Phi_T = (model.C @ model.A @ model.C_inv).T
        self._G_T = (model.C @ model.B).T
        self.reset(t0)

    def reset(self, t0: float) -> None:
        """Start over at time ``t0`` (s), e.g. after a gap in the stream: nothing before it is used."""
        m, p = self.setup.model.n_outputs, self.setup.model.n_inputs
        self.t0 = float(t0)
        self._z = np.empty((0, m))  # raw samples from index self._first on
        self._u = np.empty((0, p))
        self._first = 0  # global index of self._z[0]
        self._next_block = 0  # block b covers regressor indices 1 + b H .. (b + 1) H
        self._history: list[IdentificationMoments] = []  # the last n - 1 blocks

    @property
    def window_s(self) -> float:
        """Window length (s)."""
        return self.n * self.H * self.dt

    def windows_by(self, samples: int) -> int:
        """Windows complete (hop numbers below this) once ``samples`` raw samples have been pushed since
        the start or the last reset."""
        return max(0, (samples - 2) // self.H - self.n + 1)

    def share(
        self, found: OnlineIdentification, samples: int
    ) -> tuple[OnlineIdentification, OnlineIdentification]:
        """Split the windows ``found`` of a push that ran ahead: those complete once ``samples`` raw samples
        are in (since the start or the last reset; none of ``found`` complete before its first window), and
        the rest.

        The first part is what pushing up to ``samples`` would have given, to the bit: a window's fit does
        not depend on the other windows fitted with it, as long as there is at least one. A single window
        alone takes other array layouts (the last bits of some sums differ), so a share of one window is
        fitted again alone, as a push that completes only it fits it.
        """
        k = 0 if found.n_windows == 0 else max(0, self.windows_by(samples) - int(found.frames[0]))
        mine, rest = found.take(slice(0, k)), found.take(slice(k, None))
        if k == 1:
            assert mine.result is not None  # (one window)
            alone = identify_moments(
                self.setup, mine.result.moments, alpha=self.alpha, confidence=self.confidence
            )
            mine = dataclasses.replace(mine, result=alone)
        return mine, rest

    def push(self, z: np.ndarray, u: np.ndarray) -> OnlineIdentification:
        """Feed ``z (K, m)`` and ``u (K, p)`` (the monitor's raw push); identify every completed window.

        Raises
        ------
        ShapeError, NonFiniteError
            On wrong shapes or NaN/inf samples.
        """
        m, p = self.setup.model.n_outputs, self.setup.model.n_inputs
        z = (
            finite_array("z", z, ndim=(1, 2)).reshape(-1, m)
            if np.ndim(z) == 1
            else finite_array("z", z, ndim=2)
        )
        u = finite_array("u", u, ndim=(1, 2))
        u = u.reshape(-1, p) if u.ndim == 1 else u
        if z.shape[1] != m or u.shape != (z.shape[0], p):
            raise ShapeError(f"z must have shape (K, {m}) and u (K, {p}); got {z.shape} and {u.shape}")
        # the samples held back from the last push, then these (the caller's own arrays when none were
        # held back: a replay's whole record is not copied; only the tail kept for the next push is)
        held = self._z.shape[0] > 0
        z = np.concatenate([self._z, z]) if held else z
        u = np.concatenate([self._u, u]) if held else u
        # block b needs raw samples b H .. (b + 1) H + 1 (z(k-1) .. z(k+1) for k = 1 + b H .. (b + 1) H)
        have = self._first + z.shape[0]  # raw samples received
        n_new = max(0, (have - 2) // self.H - self._next_block)
        empty = OnlineIdentification(np.empty(0, dtype=int), np.empty(0), np.empty((0, 2)), None)
        if n_new == 0:  # keep them all (a copy of the caller's arrays; the concatenation is one already)
            self._z, self._u = (z, u) if held else (z.copy(), u.copy())
            return empty
        blocks = self._blocks(z, u, n_new)
        b0 = self._next_block
        self._next_block += n_new
        keep_from = self._next_block * self.H - self._first  # raw index of the next block's start
        self._z, self._u = z[keep_from:].copy(), u[keep_from:].copy()
        self._first += keep_from
        everything = [*self._history, blocks]
        allb = _stack(everything)
        n_prev = allb.runs - n_new
        self._history = [_take(allb, slice(max(0, allb.runs - (self.n - 1)), None))] if self.n > 1 else []
        ends = np.arange(n_prev, allb.runs)  # window ends (block index in allb)
        ends = ends[ends >= self.n - 1]
        if ends.size == 0:
            return empty
        windows = _windows(allb, ends, self.n)
        frames = b0 + (ends - n_prev) - (self.n - 1)
        result = identify_moments(self.setup, windows, alpha=self.alpha, confidence=self.confidence)
        # window j: regressors 1 + j H .. j H + W, chattering e(k+1) at t0 + (k + 1) dt
        first_e = self.t0 + (frames * self.H + 2) * self.dt
        span = self.n * self.H * self.dt
        times = first_e + (self.n * self.H - 1) / 2.0 * self.dt
        win = np.stack([first_e, first_e + span], axis=1)
        return OnlineIdentification(frames=frames, times_s=times, window_s=win, result=result)

    def _blocks(self, z: np.ndarray, u: np.ndarray, count: int) -> IdentificationMoments:
        """Sums of the next ``count`` blocks, stacked as realizations (``z``, ``u``: the raw samples from
        global index ``self._first`` on)."""
        H = self.H
        start = (
            self._next_block * H - self._first
        )  # raw index (in the buffer) of z(b H) = z(k-1), k = 1 + b H
        # (count, H + 2, .) views of the buffers, block b from start + b H (overlapping by two samples):
        # the samples and strides of a gathered copy, without copying
        zb, ub = _hop_blocks(z, start, count, H), _hop_blocks(u, start, count, H)
        e = zb[:, 1:] - zb[:, :-1] @ self._Phi_T - ub[:, :-1] @ self._G_T  # closed form, eq (23)
        t_first = self.t0 + (self._first + start + 2) * self.dt  # e(k+1) of the block's first k
        st = self.setup
        times = (t_first, t_first + H * self.dt)
        return compute_moments(zb, ub, e, st.J, st.L, st.R, 1, H + 1, times, st.swe_pairs)


def _hop_blocks(x: np.ndarray, start: int, count: int, H: int) -> np.ndarray:
    """Read-only ``(count, H + 2, k)`` view of the rows of ``x`` (C-contiguous ``(T, k)``): block ``b`` is
    rows ``start + b H .. start + (b + 1) H + 1``."""
    x = np.ascontiguousarray(x)
    assert start >= 0 and start + count * H + 2 <= x.shape[0]  # (the caller counts whole blocks)
    row, col = x.strides
    return np.lib.stride_tricks.as_strided(
        x[start:], shape=(count, H + 2, x.shape[1]), strides=(H * row, row, col), writeable=False
    )


def _stack(parts: list[IdentificationMoments]) -> IdentificationMoments:
    a = parts[0]

    def cat(k: str) -> np.ndarray:
        return np.concatenate([getattr(p, k) for p in parts])

    return IdentificationMoments(
        swx=cat("swx"),
        swe=cat("swe"),
        s0=cat("s0"),
        s1=cat("s1"),
        w_first=cat("w_first"),
        w_last=cat("w_last"),
        n_samples=a.n_samples,
        t_start=a.t_start,
        t_stop=a.t_stop,
    )


def _take(mom: IdentificationMoments, sl: slice) -> IdentificationMoments:
    return IdentificationMoments(
        swx=mom.swx[sl],
        swe=mom.swe[sl],
        s0=mom.s0[sl],
        s1=mom.s1[sl],
        w_first=mom.w_first[sl],
        w_last=mom.w_last[sl],
        n_samples=mom.n_samples,
        t_start=mom.t_start,
        t_stop=mom.t_stop,
        records=mom.records,
    )


def _windows(blocks: IdentificationMoments, ends: np.ndarray, n: int) -> IdentificationMoments:
    """Sums of the windows of ``n`` consecutive blocks ending at ``ends`` (the S1 pairs across
    block boundaries added from the edge vectors), stacked as realizations. The blocks are added
    in a fixed order, so a window's bits do not depend on how the stream was cut into pushes."""
    starts = ends + 1 - n
    out = {k: getattr(blocks, k)[starts].copy() for k in _FIELDS}
    for i in range(1, n):
        for k in _FIELDS:
            out[k] += getattr(blocks, k)[starts + i]
        # the pair (last sample of block starts + i - 1, first of block starts + i)
        out["s1"] += blocks.w_last[starts + i - 1][:, :, None] * blocks.w_first[starts + i][:, None, :]
    return IdentificationMoments(
        **out,
        w_first=blocks.w_first[starts],
        w_last=blocks.w_last[ends],
        n_samples=n * blocks.n_samples,
        t_start=float("nan"),  # per window: OnlineIdentification.window_s
        t_stop=float("nan"),
    )


def hop_windows(
    setup: IdentificationSetup,
    z: np.ndarray,
    u: np.ndarray,
    *,
    hop_samples: int,
    window_hops: int,
    t0: float = 0.0,
) -> tuple[np.ndarray, np.ndarray, IdentificationMoments]:
    """The sums of every hop's window of whole records at once: :class:`OnlineIdentifier`'s windows of
    each realization, vectorized over realizations and hops.

    Parameters
    ----------
    setup : IdentificationSetup
    z : (runs, T, m) array
        Measurements (finite: simulated or checked data).
    u : (T, p) or (runs, T, p) array
        Inputs.
    hop_samples, window_hops : int
        As :class:`OnlineIdentifier`.
    t0 : float
        Time (s) of ``z[:, 0]``.

    Returns
    -------
    frames : (W,) int array
        Window (hop) numbers (the monitor's frame numbers).
    times_s : (W,) array
        Window centre times (s).
    moments : IdentificationMoments
        ``runs * W`` realizations, run-major (window ``j`` of run ``r`` at ``r * W + j``).
    """
    H, n = positive_int("hop_samples", hop_samples), positive_int("window_hops", window_hops)
    z = z[None] if z.ndim == 2 else z
    runs, T, m = z.shape
    u = u.reshape(T, -1) if u.ndim == 1 else u
    count = max(0, (T - 2) // H)  # blocks: raw samples b H .. (b + 1) H + 1
    W = count - n + 1
    if W < 1:
        raise ShapeError(
            f"records of {T} samples hold {count} hop(s) of {H} samples; a window needs {n} (give longer "
            "records)"
        )
    model = setup.model
    Phi_T, G_T = (model.C @ model.A @ model.C_inv).T, (model.C @ model.B).T
    idx = np.arange(count)[:, None] * H + np.arange(H + 2)[None, :]
    zb = z[:, idx].reshape(runs * count, H + 2, m)
    p = u.shape[-1]
    ub = np.broadcast_to(u[idx] if u.ndim == 2 else u[:, idx], (runs, count, H + 2, p)).reshape(-1, H + 2, p)
    e = zb[:, 1:] - zb[:, :-1] @ Phi_T - ub[:, :-1] @ G_T  # closed form, eq (23)
    st = setup
    blocks = compute_moments(
        zb, ub, e, st.J, st.L, st.R, 1, H + 1, (float("nan"), float("nan")), st.swe_pairs
    )
    ends = (np.arange(runs)[:, None] * count + np.arange(n - 1, count)[None, :]).ravel()
    frames = np.arange(W)
    dt = model.dt
    times = t0 + (frames * H + 2) * dt + (n * H - 1) / 2.0 * dt
    return frames, times, _windows(blocks, ends, n)
