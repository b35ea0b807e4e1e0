"""What identification estimates for a model, and the estimation itself (private module).

See :mod:`chatterspec.detection.identification` for the method; this module holds the
:class:`IdentificationSetup` (entries, regressors and hypotheses of one model) and
:func:`fit_moments` (instrumental variables, the lag-1 sandwich covariance, the
minimum-distance fit of each hypothesis and the selection), vectorized over realizations.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
import scipy.special

from ..errors import IdentifiabilityError, ParameterError
from ..plants.models import LinearModel
from ..plants.nonlinear import Model, is_linear
from ..plants.parameters import NO_FAULT, UNEXPLAINED, Hypothesis, ParameterMap
from ._identification_moments import IdentificationMoments

__all__ = ["EXCITATION_SIGMAS", "MAX_CONDITION", "IdentificationSetup", "build_setup", "fit_moments"]

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
    # its result does not depend on the others in the batch (a stream cut into other pushes)
    live = np.arange(runs)
    step = np.zeros_like(theta)
    eye = np.eye(theta.shape[1])
    n_live = -1
    for _ in range(60):
        if live.size != n_live:  # (live only shrinks: the same size is the same realizations)
            n_live = live.size
            Wl, Tl, al, dnl = W[live], T[live], active[live], dn[live]
        th = theta[live]
        G, g = setup.jacobian_deviations(h, th)  # (live, D, p), (live, D)
        r = np.einsum("rab,rb->ra", Wl, dnl - np.where(al, g / Tl, 0.0))
        Gt = np.einsum("rab,rbk->rak", Wl, np.where(al[:, :, None], G / Tl[:, :, None], 0.0))
        cn = np.linalg.norm(Gt, axis=1)  # (live, p)
        lost = ~(cn > 1e-12 * np.maximum(np.linalg.norm(G / Tl[:, :, None], axis=1), 1e-300))
        lost_any = lost.any(axis=1)
        why[live] = np.where(lost_any & ok[live], 1, why[live])
        ok[live] &= ~lost_any
        cn = np.where(cn > 0, cn, 1.0)
        Gs = Gt / cn[:, None, :]
        N = Gs.transpose(0, 2, 1) @ Gs
        apart = _separable(N, ok[live])
        why[live] = np.where(~apart & ok[live], 4, why[live])
        ok[live] &= apart
        okl = ok[live]
        N = N + np.where(okl, 0.0, 1.0)[:, None, None] * eye
        st = np.linalg.solve(N, np.einsum("rak,ra->rk", Gs, r)[..., None])[..., 0] / cn
        st = np.where(okl[:, None], st, 0.0)
        theta[live] = th + st
        step[live] = st
        done = np.all(np.abs(st) <= 1e-10 * (np.abs(theta[live]) + 1e-6 * scale), axis=1)
        live = live[~done]
        if live.size == 0:
            break
    else:
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
    when the estimated entries do not deviate, None when no declared hypothesis explains it."""
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
