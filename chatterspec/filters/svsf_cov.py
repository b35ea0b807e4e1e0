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
from . import _engine, _engine_numpy
from ._base import CovarianceFilterBase, check_model, is_linear
from ._engine import NOT_PD, map_step, map_update_step, svsf_offsets
from ._luen import luen_correction, luen_first_order
from .kalman import kalman_correct
from .svsf_coordinates import reduced_order_transform

__all__ = ["Mapping", "SVSFCov", "mapping_matrix"]

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
            Kkf = _engine_numpy.kalman_gain_numpy(pr.S, pr.PCt) if self.vbl else None
            Mp = _engine_numpy.map_numpy(mapping, pr.D, pr.PCt, M, pr.e.shape[0])
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
        step = vbl_correct if self.vbl else svsf_cov_correct
        return _engine.CorrectionStep("vbl" if self.vbl else "svsf", step, fp, numpy, mapping)


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
