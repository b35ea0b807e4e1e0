"""SVSF with covariance: [SMM] eq (2.1)-(2.10), in the division-free gain form (``docs/design.md`` §7.2).

Per sample, for every realization::

    (2.1)  x(k+1|k) = f(x(k|k), u(k))                       (linear: A x + B u)
    (2.2)  P(k+1|k) = F P(k|k) F^T + Q                       (F: Jacobian; linear: A)
    (2.3)-(2.4)  e(k+1|k) = z(k+1) - C x(k+1|k)
    (2.5)  K = M diag(kappa),  kappa_i = (|e_i(k+1|k)| + gamma_i |e_i(k|k)|) / max(|e_i(k+1|k)|, psi_i)
    (2.8)  x(k+1|k+1) = x(k+1|k) + K e(k+1|k)
    (2.9)  P(k+1|k+1) = (I - K C) P(k+1|k) (I - K C)^T + K R K^T     (Joseph form)
    (2.10) e(k+1|k+1) = z(k+1) - C x(k+1|k+1)

``kappa`` is eq (2.5)'s ``diag[(|e| + gamma |e(k|k)|) o sat(psi^-1 e)] diag(e)^-1`` with the
division by ``e`` carried out analytically (``sat(e/psi)/e = 1/max(|e|, psi)`` for ``e != 0``): no
singularity at ``e = 0`` (tested equal to eq 2.5 wherever ``e != 0``). The gain does not depend on
``P``; the covariance is bookkeeping that feeds the innovation covariance ``S`` and the
log-likelihood a multiple-model bank weighs ([SMM] eq 3.3).

``M`` maps the output-space correction to the states (``docs/design.md`` §7.4):

* ``"full"``: ``C^-1`` (C square, e.g. [SMM]'s C = I4);
* ``"pinv"``: ``C^+`` ([SMM] eq 2.5 read literally; only the measured states move);
* ``"cov"``: ``P(k+1|k) C^T (C P(k+1|k) C^T)^-1``, a covariance regression of the unmeasured on
  the measured errors (default when C is not square).

* ``"luen"``: the reduced-order Luenberger form (chattering paper eq 9-11, ``docs/design.md`` §7.4)
  with ``Phi`` the model Jacobian at ``x(k|k)``; needs ``n = 2m`` and ``Phi12`` invertible, and
  ``psi`` for all n coordinates (measured first). Same estimates as
  :class:`chatterspec.filters.svsf.SVSF` for a linear model (tested); numpy path only.

**Reduced-order (Luenberger) correction** (``luen``, shared with the second-order SVSF). In
measurement-aligned coordinates ``y = T x`` (``C T^-1 = [I 0]``), ``Phi = T F T^-1`` and
``A_l = Phi22 Phi12^-1`` (n = 2m, Phi12 invertible):

* first order (chattering paper eq 9-11): ``d_u = kappa_u o e``, ``d_l = kappa_l o (A_l e)``
  with ``kappa_u = (|e| + g|ebar|)/max(|e|, psi_u)``,
  ``kappa_l = (|A_l e| + g|Phi12^-1 ebar|)/max(|A_l e|, psi_l)``;
  gain ``[diag(kappa_u); diag(kappa_l) A_l]`` (exact: ``K e = d``);
* second order: ``d_u = e - r``, ``d_l = A_l e - Phi12^-1 r``, ``r = (g + L) ebar - g L ebar(k-1)``;
  covariance gain ``[diag(q); A_l diag(q)]`` with ``q = clip(d_u / e)`` (exact when r = 0).

Then ``K = T^-1 Ky`` and ``x(k+1|k+1) = x(k+1|k) + T^-1 [d_u; d_l]``. :func:`luen_correction` is
the numpy form (vectorized over realizations); :func:`luen_first_order` and
:func:`luen_second_order` the compiled steps the IMM bank's loop inlines (parameters in ``fp``,
:func:`chatterspec.filters._engine.svsf_parameters`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import cast

import numpy as np
import numpy.typing as npt

from .. import _jit
from .._repr import short_repr
from .._validate import finite_array
from ..errors import ParameterError, ShapeError, SingularMatrixError
from ..plants.nonlinear import Model, require_linear_measurement
from ..plants.scenarios import FilterSettings, StateMapping
from . import _engine
from ._base import CovarianceFilterBase, check_model, is_linear
from ._engine import NOT_PD, SINGULAR_PHI12, SVSF2, map_step, map_update_step, product_step, svsf_offsets
from .kalman import kalman_correct
from .svsf import reduced_order_transform

__all__ = [
    "Mapping",
    "SVSFCov",
    "mapping_matrix",
]


# ----------------------------------------------------------------------------- (from svsf_cov)
Mapping = StateMapping


def mapping_matrix(C: np.ndarray, mapping: str) -> np.ndarray | None:
    """The constant output-to-state map of ``mapping`` (None for ``"cov"``, which changes each step).

    Parameters
    ----------
    C : (m, n) array
        Measurement matrix.
    mapping : {"full", "pinv", "cov"}
        ``"full"`` = ``C^-1`` (needs m = n and C invertible), ``"pinv"`` = ``C^+``.

    Returns
    -------
    (n, m) array or None

    Raises
    ------
    SingularMatrixError
        ``"full"`` with a non-square or singular C.
    ParameterError
        Unknown mapping.
    """
    C = finite_array("C", C, ndim=2)
    m, n = C.shape
    if mapping == "full":
        if m != n:
            raise SingularMatrixError(
                f"mapping='full' needs a square invertible C (C^-1 in eq 2.5/9); C is {m}x{n}: "
                "use mapping='cov' or 'pinv' for fewer measurements than states"
            )
        if np.linalg.cond(C) > 1e12:
            raise SingularMatrixError("mapping='full' needs C^-1 but C is singular (condition number > 1e12)")
        return np.linalg.inv(C)
    if mapping == "pinv":
        return np.linalg.pinv(C)
    if mapping in ("cov", "luen"):
        return None
    raise ParameterError(f"mapping must be 'full', 'pinv', 'cov' or 'luen'; got {mapping!r}")


def luen_transform(C: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(T, T^-1)`` of the reduced-order form, ``T = [[C], [E_l]]``; needs ``n = 2m`` (square Phi12)."""
    m, n = np.shape(C)
    if n != 2 * m:
        raise SingularMatrixError(
            f"mapping='luen' needs n = 2m (Phi12 square and invertible, eq 10); C is {m}x{n}: "
            "use mapping='cov' or 'pinv'"
        )
    return reduced_order_transform(np.asarray(C, dtype=float))


def default_mapping(C: np.ndarray) -> StateMapping:
    """``"full"`` when C is square and well conditioned, else ``"cov"`` (``docs/design.md`` §7.4)."""
    m, n = np.shape(C)
    return "full" if m == n and np.linalg.cond(C) <= 1e12 else "cov"


def per_channel(name: str, value: npt.ArrayLike, m: int, *, rule: str) -> np.ndarray:
    """Scalar or (m,) parameter as a float (m,) array (finite)."""
    arr = np.atleast_1d(finite_array(name, value, ndim=(0, 1)))
    if arr.size == 1:
        arr = np.full(m, float(arr[0]))
    if arr.shape != (m,):
        raise ShapeError(
            f"{name} must be a scalar or have {m} entries (one per output, {rule}); got {arr.size}"
        )
    return np.ascontiguousarray(arr, dtype=float)


class SVSFCovarianceBase(CovarianceFilterBase):
    """What the SVSF-type covariance filters share (:class:`SVSFCov`, the second-order SVSF).

    A subclass is a frozen dataclass with the fields ``model``, ``gamma``, ``mapping``, ``_M`` and
    ``_luen``; :meth:`_check_mapping` checks the model and resolves the mapping in its
    ``__post_init__``, and :meth:`_sizes` gives what its ``_correction_step`` starts from.
    """

    mapping: Mapping | None
    _M: np.ndarray | None
    _luen: tuple[np.ndarray, np.ndarray] | None

    def _check_mapping(self, who: str) -> int:
        """Check the model (linear measurement ``C``, named ``who`` in errors), set ``mapping``, ``_M``,
        ``_luen`` (:func:`resolve_mapping`); return the number of outputs m."""
        check_model(self.model)
        require_linear_measurement(self.model, who)
        C = np.asarray(self.model.C, dtype=float)
        mapping, M, luen = resolve_mapping(C, self.mapping)
        object.__setattr__(self, "_M", M)
        object.__setattr__(self, "mapping", mapping)
        object.__setattr__(self, "_luen", luen)
        return int(self.model.n_outputs)

    @property
    def _linear(self) -> bool:
        return is_linear(self.model)

    def _sizes(self) -> tuple[int, int, int]:
        """``(mapping, n, m)`` of the correction step (``mapping``: the code of ``_M``/``_luen``)."""
        n, m = int(self.model.n_states), int(self.model.n_outputs)
        return _mapping_code(self._M, self._luen), n, m


@dataclass(frozen=True, eq=False)
class SVSFCov(SVSFCovarianceBase):
    """SVSF with covariance ([SMM] eq 2.1-2.10), batched over realizations.

    Implements the :class:`~chatterspec.filters.protocol.Filter` protocol. Covariances are per
    run ``(runs, n, n)``: the gain depends on the data.

    Parameters
    ----------
    model : model object
        LinearModel (compiled loop over time) or any model with ``transition``, ``jacobian``,
        ``C``, ``Q``, ``R``, ``dt``, ``n_states``, ``n_outputs``, ``n_inputs``.
    psi : float or (m,) array
        Smoothing boundary layer per output channel (> 0), in output units.
    gamma : float or (m,) array
        Convergence rate, ``0 < gamma < 1`` ([SMM] eq 2.5).
    mapping : {"full", "pinv", "cov", "luen"}, optional
        Output-to-state map (module docstring); default ``"full"`` for a square invertible C,
        else ``"cov"``. With ``"luen"``, ``psi`` has n entries (measured coordinates first).
    vbl : bool
        Variable boundary layer (``docs/design.md`` §7.2, beyond the papers, which never define
        it): use the Kalman gain ``K_KF = P C^T S^-1`` when
        ``psi_vbl,i = (|e_i| + gamma_i |e_i(k|k)|) / (C K_KF)_ii <= psi_i`` in every channel,
        else the fixed-``psi`` SVSF gain. Inside the layer it equals the Kalman filter (tested).

    Raises
    ------
    ParameterError
        ``psi <= 0``, ``gamma`` outside (0, 1), unknown mapping.
    SingularMatrixError
        ``mapping="full"`` with a non-square or singular C.
    """

    __repr__ = short_repr  # shapes and key figures, never whole arrays

    model: Model
    psi: float | np.ndarray
    gamma: float | np.ndarray = 0.1
    mapping: Mapping | None = None
    vbl: bool = False
    _M: np.ndarray | None = field(init=False, repr=False, default=None)
    _luen: tuple[np.ndarray, np.ndarray] | None = field(init=False, repr=False, default=None)

    def __post_init__(self) -> None:
        if not isinstance(self.vbl, bool | np.bool_):
            raise ParameterError(f"vbl must be True or False; got {self.vbl!r}")
        m = self._check_mapping("SVSFCov")
        if self._luen is not None and self.vbl:
            raise ParameterError("vbl=True is not available with mapping='luen'")
        n_psi = int(self.model.n_states) if self._luen is not None else m
        object.__setattr__(self, "psi", check_psi(self.psi, n_psi))
        object.__setattr__(self, "gamma", check_gamma(self.gamma, m))

    def _correction_step(self) -> _engine.CorrectionStep:
        mapping, n, m = self._sizes()
        gamma_, psi_ = cast(np.ndarray, self.gamma), cast(np.ndarray, self.psi)  # arrays after __post_init__
        fp = _engine.svsf_parameters(mapping, n, m, gamma_, psi=psi_, M=self._M, luen=self._luen)
        gamma, psi, M, luen = cast(np.ndarray, self.gamma), cast(np.ndarray, self.psi), self._M, self._luen

        def numpy(pr: _engine.NumpyPrior) -> tuple[np.ndarray, np.ndarray]:
            if luen is not None:
                Kg, dx = luen_correction(
                    _engine.SVSF1, pr.F, pr.e, pr.ep, pr.epp, *luen, gamma, 0 * gamma, psi, 0.0, 2.0
                )
                return Kg, pr.xp + dx
            Kkf = _engine.kalman_gain_numpy(pr.S, pr.PCt) if self.vbl else None
            Mp = _engine.map_numpy(mapping, pr.D, pr.PCt, M, pr.e.shape[0])
            a = np.abs(pr.e)
            g = (a + gamma * np.abs(pr.ep)) / np.maximum(a, psi)
            Kg = Mp * g[:, None, :]
            x = pr.xp + np.einsum("rij,rj->ri", Mp, g * pr.e)
            if Kkf is not None:  # (self.vbl)
                ck = np.einsum("iq,rqi->ri", pr.C, Kkf)
                use_kf = np.all((ck > 0.0) & (np.abs(pr.e) + gamma * np.abs(pr.ep) <= psi * ck), axis=1)
                Kg = np.where(use_kf[:, None, None], Kkf, Kg)
                x = np.where(use_kf[:, None], pr.xp + np.einsum("rij,rj->ri", Kkf, pr.e), x)
            return Kg, x

        if luen is not None:
            return _engine.CorrectionStep("svsf_luen", luen_first_order, fp, numpy, mapping)
        if self.vbl:
            return _engine.CorrectionStep("vbl", vbl_correct, fp, numpy, mapping)
        return _engine.CorrectionStep("svsf", svsf_cov_correct, fp, numpy, mapping, lanes=True)


@_jit.step
def _svsf_gain(fp: np.ndarray, e: np.ndarray, ep: np.ndarray, xp: np.ndarray, PCtT: np.ndarray, D: np.ndarray,
    L: np.ndarray, x: np.ndarray, KgT: np.ndarray, ws: tuple[np.ndarray, ...], n: int,
    m: int) -> bool:  # fmt: skip
    """[SMM] eq (2.5), (2.8) for the constant and ``cov`` maps: ``g_i = (|e_i| + gamma_i |e_i(k|k)|) /
    max(|e_i|, psi_i)``, ``dz = g o e``, ``K = M diag(g)``, ``x = x(k+1|k) + M dz``; False if ``C P C^T``
    is not positive definite (``cov``)."""
    MpT, g, dz = ws[14], ws[15], ws[16]
    o_g, _, o_psi, _, o_M, _, _ = svsf_offsets(n, m)
    if not map_step(int(fp[0]), D, L, PCtT, fp, o_M, MpT, n, m):
        return False
    for i in range(m):
        a = abs(e[i])
        den = a if a > fp[o_psi + i] else fp[o_psi + i]
        g[i] = (a + fp[o_g + i] * abs(ep[i])) / den
        dz[i] = g[i] * e[i]
    map_update_step(xp, MpT, g, dz, x, KgT, n, m)
    return True


@_jit.step
def svsf_cov_correct(fp: np.ndarray, e: np.ndarray, ep: np.ndarray, epp: np.ndarray, xp: np.ndarray,
    PCtT: np.ndarray, D: np.ndarray, L: np.ndarray, C: np.ndarray, F: np.ndarray, x: np.ndarray,
    KgT: np.ndarray, ws: tuple[np.ndarray, ...], n: int, m: int) -> int:  # fmt: skip
    """The SVSF-with-covariance correction (compiled step, signature of :mod:`chatterspec.filters._engine`).

    ``fp`` from :func:`~chatterspec.filters._engine.svsf_parameters`; constant or ``cov`` map.
    """
    if not _svsf_gain(fp, e, ep, xp, PCtT, D, L, x, KgT, ws, n, m):
        return NOT_PD
    return 0


@_jit.step
def vbl_correct(fp: np.ndarray, e: np.ndarray, ep: np.ndarray, epp: np.ndarray, xp: np.ndarray,
    PCtT: np.ndarray, D: np.ndarray, L: np.ndarray, C: np.ndarray, F: np.ndarray, x: np.ndarray,
    KgT: np.ndarray, ws: tuple[np.ndarray, ...], n: int, m: int) -> int:  # fmt: skip
    """The variable boundary layer (compiled step): the Kalman gain when every channel has
    ``psi_vbl,i = (|e_i| + gamma_i |e_i(k|k)|) / (C K_KF)_ii <= psi_i``, else :func:`svsf_cov_correct`."""
    kalman_correct(fp, e, ep, epp, xp, PCtT, D, L, C, F, x, KgT, ws, n, m)
    o_g, _, o_psi, _, _, _, _ = svsf_offsets(n, m)
    use_kf = True
    for i in range(m):
        ck = 0.0
        for q in range(n):
            ck += C[i, q] * KgT[i, q]
        need = abs(e[i]) + fp[o_g + i] * abs(ep[i])
        if not (ck > 0.0 and need <= fp[o_psi + i] * ck):
            use_kf = False
    if use_kf:
        return 0
    if not _svsf_gain(fp, e, ep, xp, PCtT, D, L, x, KgT, ws, n, m):
        return NOT_PD
    return 0


def from_settings(model: Model, settings: FilterSettings, source: str) -> SVSFCov:
    """Registry builder of ``svsf``: psi, gamma (default 0.1) and mapping of ``settings``.

    With the ``luen`` mapping the boundary layer is ``psi`` of the measured then ``psi_lower`` of
    the unmeasured coordinates.

    Raises
    ------
    ParameterError
        ``settings`` gives no ``psi`` (or no ``psi_lower`` with ``luen``).
    """
    fs = settings
    if fs.psi is None:
        raise ParameterError(f"scenario {source!r} gives no boundary layer psi for the first-order SVSF")
    psi = fs.psi
    if fs.mapping == "luen":
        if fs.psi_lower is None:
            raise ParameterError(f"scenario {source!r}: mapping 'luen' needs psi_lower in its settings")
        psi = fs.psi + fs.psi_lower
    gamma = 0.1 if fs.gamma is None else fs.gamma
    return SVSFCov(model, psi=np.asarray(psi, dtype=float), gamma=gamma, mapping=fs.mapping)


def check_psi(psi: npt.ArrayLike, n_psi: int) -> np.ndarray:
    """The smoothing boundary layer per channel (scalar or ``n_psi`` values), all > 0, else ParameterError."""
    psi = per_channel("psi", psi, n_psi, rule="the boundary layer")
    if np.any(psi <= 0):
        raise ParameterError(f"psi must be > 0 (smoothing boundary layer, output units); got {psi.tolist()}")
    return psi


def resolve_mapping(C: np.ndarray, mapping: str | None) -> tuple[str, np.ndarray | None, tuple | None]:
    """``(mapping, M, luen)``: the mapping (default :func:`default_mapping`), its constant matrix
    (:func:`mapping_matrix`) and, for ``"luen"``, the reduced-order transform (:func:`luen_transform`)."""
    mapping = default_mapping(C) if mapping is None else mapping
    M = mapping_matrix(C, mapping)
    return mapping, M, luen_transform(C) if mapping == "luen" else None


def check_gamma(gamma: npt.ArrayLike, m: int) -> np.ndarray:
    """``gamma`` per channel in the open interval (0, 1), else ParameterError."""
    g = per_channel("gamma", gamma, m, rule="the convergence rate")
    if np.any((g <= 0) | (g >= 1)):
        raise ParameterError(
            f"gamma must lie in the open interval (0, 1) for every channel (convergence rate, "
            f"0 < gamma_ii < 1); got {g.tolist()}"
        )
    return g


def _mapping_code(M: np.ndarray | None, luen: tuple[np.ndarray, np.ndarray] | None) -> int:
    if luen is not None:
        return _engine.MAP_LUEN
    return _engine.MAP_COV if M is None else _engine.MAP_CONST


# ----------------------------------------------------------------------------- reduced-order form
def luen_correction(
    kind: int,
    F: np.ndarray,
    e: np.ndarray,
    ep: np.ndarray,
    epp: np.ndarray,
    T: np.ndarray,
    Tinv: np.ndarray,
    gamma: np.ndarray,
    lam: np.ndarray,
    psi: np.ndarray,
    lo: float,
    hi: float,
) -> tuple[np.ndarray, np.ndarray]:
    """The correction of the module docstring, numpy: ``(K (runs, n, m), dx (runs, n))``."""
    runs, m = e.shape
    Phi = np.broadcast_to(T @ F @ Tinv, (runs, 2 * m, 2 * m))
    try:
        P12i = np.linalg.inv(Phi[:, :m, m:])
    except np.linalg.LinAlgError:
        raise SingularMatrixError(
            "the Luenberger form needs Phi12 = d(measured)/d(unmeasured) invertible at the estimate (eq 10)"
        ) from None
    Al = Phi[:, m:, m:] @ P12i
    Ae = np.einsum("rij,rj->ri", Al, e)
    if kind == SVSF2:
        r = (gamma + lam) * ep - gamma * lam * epp
        du = e - r
        dl = Ae - np.einsum("rij,rj->ri", P12i, r)
        with np.errstate(divide="ignore", invalid="ignore"):
            q = np.where(e != 0.0, np.clip(du / np.where(e != 0.0, e, 1.0), lo, hi), 1.0)
        Ky = np.concatenate([q[:, :, None] * np.eye(m), Al * q[:, None, :]], axis=1)
    else:
        a = np.abs(e)
        ku = (a + gamma * np.abs(ep)) / np.maximum(a, psi[:m])
        al = np.abs(Ae)
        kl = (al + gamma * np.abs(np.einsum("rij,rj->ri", P12i, ep))) / np.maximum(al, psi[m:])
        du, dl = ku * e, kl * Ae
        Ky = np.concatenate([ku[:, :, None] * np.eye(m), kl[:, :, None] * Al], axis=1)
    return Tinv @ Ky, np.concatenate([du, dl], axis=1) @ Tinv.T


# ----------------------------------------------------------------------------- compiled steps
@_jit.step
def invert_step(A: np.ndarray, Ainv: np.ndarray, W: np.ndarray, m: int) -> bool:  # pragma: no cover
    """Ainv = A^-1, Gauss-Jordan with partial pivoting (scratch ``W`` (m, 2m)); False if singular."""
    for i in range(m):
        for j in range(m):
            W[i, j] = A[i, j]
            W[i, m + j] = 1.0 if i == j else 0.0
    for c in range(m):
        piv = c
        for i in range(c + 1, m):
            if abs(W[i, c]) > abs(W[piv, c]):
                piv = i
        if W[piv, c] == 0.0:
            return False
        if piv != c:
            for j in range(2 * m):
                t = W[c, j]
                W[c, j] = W[piv, j]
                W[piv, j] = t
        d = W[c, c]
        for j in range(2 * m):
            W[c, j] = W[c, j] / d
        for i in range(m):
            if i != c:
                f = W[i, c]
                if f != 0.0:
                    for j in range(2 * m):
                        W[i, j] = W[i, j] - f * W[c, j]
    for i in range(m):
        for j in range(m):
            Ainv[i, j] = W[i, m + j]
    return True


@_jit.step
def _phi_blocks(
    fp: np.ndarray, F: np.ndarray, e: np.ndarray, ws: tuple, n: int, m: int
) -> bool:  # pragma: no cover
    """``Phi = T F T^-1``, ``Phi12^-1`` (``P12i``), ``A_l = Phi22 Phi12^-1`` and ``A_l e`` into ``ws``."""
    T1, Phi, G12, P12i, Al, Ae, W = ws[0], ws[17], ws[18], ws[19], ws[20], ws[21], ws[25]
    _, _, _, _, _, o_T, o_Ti = svsf_offsets(n, m)
    product_step(fp[o_T : o_T + n * n].reshape((n, n)), F, T1, n, n, n, False, False)
    product_step(T1, fp[o_Ti : o_Ti + n * n].reshape((n, n)), Phi, n, n, n, False, False)
    for i in range(m):
        for jj in range(m):
            G12[i, jj] = Phi[i, m + jj]
    if not invert_step(G12, P12i, W, m):
        return False
    product_step(Phi[m:, m:], P12i, Al, m, m, m, False, False)
    product_step(Al, e.reshape((m, 1)), Ae.reshape((m, 1)), m, 1, m, False, False)
    return True


@_jit.step
def _luen_update(
    fp: np.ndarray, xp: np.ndarray, x: np.ndarray, KgT: np.ndarray, ws: tuple, n: int, m: int
) -> None:  # pragma: no cover - compiled
    """``K = T^-1 Ky`` (into ``KgT``) and ``x = x(k+1|k) + T^-1 dy``."""
    dy, Ky = ws[23], ws[24]
    o_Ti = svsf_offsets(n, m)[6]
    Tinv = fp[o_Ti : o_Ti + n * n].reshape((n, n))
    product_step(Tinv, Ky, KgT.T, n, m, n, False, False)
    for i in range(n):
        s = 0.0
        for t in range(n):
            s += dy[t] * Tinv[i, t]
        x[i] = xp[i] + s


def _luen_correct(fp: np.ndarray, e: np.ndarray, ep: np.ndarray, epp: np.ndarray, xp: np.ndarray,
    PCtT: np.ndarray, D: np.ndarray, L: np.ndarray, C: np.ndarray, F: np.ndarray, x: np.ndarray,
    KgT: np.ndarray, ws: tuple[np.ndarray, ...], n: int, m: int) -> int:  # fmt: skip
    """The reduced-order correction of the module docstring, first or (``SECOND``) second order (the
    correction-step signature of :mod:`chatterspec.filters._engine`); returns 0 or ``SINGULAR_PHI12``.

    A template: :data:`luen_first_order` and :data:`luen_second_order` bind ``SECOND``.
    """
    if not _phi_blocks(fp, F, e, ws, n, m):
        return SINGULAR_PHI12
    P12i, Al, Ae, g, rr, dy, Ky = ws[19], ws[20], ws[21], ws[15], ws[22], ws[23], ws[24]
    o_g, o_l, o_psi, o_lo, _, _, _ = svsf_offsets(n, m)
    if SECOND:
        lo, hi = fp[o_lo], fp[o_lo + 1]
        for i in range(m):
            gi, li = fp[o_g + i], fp[o_l + i]
            rr[i] = (gi + li) * ep[i] - gi * li * epp[i]
        for i in range(m):
            dy[i] = e[i] - rr[i]
            s = Ae[i]
            for q in range(m):
                s -= P12i[i, q] * rr[q]
            dy[m + i] = s
            if e[i] != 0.0:
                q_i = dy[i] / e[i]
                g[i] = lo if q_i < lo else (hi if q_i > hi else q_i)
            else:
                g[i] = 1.0
        for i in range(m):  # Ky = [diag(q); Al diag(q)]
            for q in range(m):
                Ky[i, q] = g[q] if i == q else 0.0
                Ky[m + i, q] = Al[i, q] * g[q]
    else:
        for i in range(m):
            a = abs(e[i])
            den = a if a > fp[o_psi + i] else fp[o_psi + i]
            g[i] = (a + fp[o_g + i] * abs(ep[i])) / den
            s = 0.0
            for q in range(m):
                s += P12i[i, q] * ep[q]
            al = abs(Ae[i])
            den = al if al > fp[o_psi + m + i] else fp[o_psi + m + i]
            kl = (al + fp[o_g + i] * abs(s)) / den
            dy[i] = g[i] * e[i]
            dy[m + i] = kl * Ae[i]
            for q in range(m):  # Ky = [diag(ku); diag(kl) Al]
                Ky[i, q] = g[i] if i == q else 0.0
                Ky[m + i, q] = kl * Al[i, q]
    _luen_update(fp, xp, x, KgT, ws, n, m)
    return 0


#: Binding of :func:`_luen_correct`: the second-order correction.
SECOND = False
#: The first-order reduced-order correction (a compiled step with the correction-step signature).
luen_first_order = _jit.specialize(_luen_correct, "first", inline=True, SECOND=False)
#: The second-order reduced-order correction (a compiled step with the correction-step signature).
luen_second_order = _jit.specialize(_luen_correct, "second", inline=True, SECOND=True)
