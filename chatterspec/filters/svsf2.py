"""Dynamic second-order SVSF: [DETC] eq (5)-(24), [IMM] eq (6)-(14), (26)-(28) (``docs/design.md`` §7.3).

Per sample, for every realization::

    (5)  x(k+1|k) = f(x(k|k), u(k))                  (linear: F x + G u)
    (8)  P(k+1|k) = F P(k|k) F^T + Q
    (7)  e(k+1|k) = z(k+1) - H x(k+1|k)
    (9)  dz = e(k+1|k) - (gamma + Lambda) e(k|k) + gamma Lambda e(k-1|k-1)
    (10) x(k+1|k+1) = x(k+1|k) + M dz                 ([DETC]: M = H^-1)
    (12) K = M diag(dz) diag(e(k+1|k))^-1             ([IMM] gain form, used for the covariance)
    (14) P(k+1|k+1) = (I - K C) P(k+1|k) (I - K C)^T + K R K^T      (Joseph form)
    (17) Lambda = diag(lambda_ii),  lambda_ii = 1 / (1 + c_ii),  0 < gamma_ii < 1

``M`` is the output-to-state map of :mod:`chatterspec.filters.svsf_cov` (``full`` = H^-1,
``pinv``, ``cov``; ``luen``: ``d_u = e - r``, ``d_l = A_l e - Phi12^-1 r`` with
``r = (gamma + Lambda) e(k|k) - gamma Lambda e(k-1|k-1)``, one construction of the papers'
"combined with Luenberger's observer"). The state update uses the exact ``dz``; the
covariance gain uses the ratio ``dz_i / e_i`` clipped to ``ratio_clip`` (default [0, 2],
``docs/design.md`` I7: the ratio is unbounded as ``e -> 0``) and 1 where ``e_i = 0``
exactly (the limit when the residuals are zero). [IMM] eq (28) ``P = P - K E K^T`` holds
only for the Kalman gain, hence Joseph.

Properties (tested exactly, square H): the a-posteriori residual obeys
``e(k+1|k+1) = (gamma + Lambda) e(k|k) - gamma Lambda e(k-1|k-1)`` ([DETC] eq 21), with roots
gamma and lambda per channel; the manifold ``sigma_k = (1 + c) e(k|k) - e(k-1|k-1)`` obeys
``sigma_{k+1} = gamma sigma_k`` (printed eq 24 has (1 + lambda) where (1 + c) belongs); zero
initial residuals keep ``e(k|k) = 0``, i.e. ``x_measured = H^-1 z``, for every k.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import cast

import numpy as np

from .. import _jit
from .._repr import short_repr
from .._validate import finite_array
from ..errors import ParameterError
from ..plants.nonlinear import Model
from ..plants.scenarios import FilterSettings
from . import _engine
from ._engine import NOT_PD, map_step, map_update_step, svsf_offsets
from .svsf_cov import (
    Mapping,
    SVSFCovarianceBase,
    check_gamma,
    luen_correction,
    luen_second_order,
    per_channel,
)

__all__ = ["SecondOrderSVSF"]


@dataclass(frozen=True, eq=False)
class SecondOrderSVSF(SVSFCovarianceBase):
    """Dynamic second-order SVSF with covariance, batched over realizations.

    Implements the :class:`~chatterspec.filters.protocol.Filter` protocol. Give ``lam`` (Lambda)
    or ``cutoff`` (c, with ``lambda = 1 / (1 + c)``, eq 17), not both; neither means c = 1,
    Lambda = 0.5 (the "identity cut-off frequency matrix" of [IMM] §6, ``docs/design.md`` I6).

    Parameters
    ----------
    model : model object
        LinearModel (compiled loop over time) or any model with ``transition``, ``jacobian``,
        ``C``, ``Q``, ``R``, ``dt``, ``n_states``, ``n_outputs``, ``n_inputs``.
    gamma : float or (m,) array
        Convergence rate, ``0 < gamma < 1`` per channel.
    lam : float or (m,) array, optional
        Lambda per channel, ``0 < lam < 1``.
    cutoff : float or (m,) array, optional
        Cut-off c per channel, ``c > 0`` (dimensionless slope of the manifold ``dS + c S``).
    mapping : {"full", "pinv", "cov", "luen"}, optional
        Output-to-state map; default ``"full"`` for a square invertible H, else ``"cov"``.
        ``"luen"``: the reduced-order form of ``docs/design.md`` §7.4 (n = 2m; numpy path).
    ratio_clip : (float, float)
        Bounds of ``dz / e`` in the covariance gain (default (0, 2)); the state update is exact.

    Raises
    ------
    ParameterError
        ``gamma`` outside (0, 1); ``lam >= 1`` or ``cutoff <= 0`` (a residual root on or outside
        the unit circle: the residual never decays); ``lam <= 0``; both ``lam`` and ``cutoff``.
    SingularMatrixError
        ``mapping="full"`` with a non-square or singular H.
    """

    __repr__ = short_repr  # shapes and key figures, never whole arrays

    model: Model
    gamma: float | np.ndarray = 0.1
    lam: float | np.ndarray | None = None
    cutoff: float | np.ndarray | None = None
    mapping: Mapping | None = None
    ratio_clip: tuple[float, float] = (0.0, 2.0)
    _M: np.ndarray | None = field(init=False, repr=False, default=None)
    _luen: tuple[np.ndarray, np.ndarray] | None = field(init=False, repr=False, default=None)

    def __post_init__(self) -> None:
        m = self._check_mapping("SecondOrderSVSF")
        object.__setattr__(self, "gamma", check_gamma(self.gamma, m))
        if self.lam is not None and self.cutoff is not None:
            raise ParameterError("give lam (Lambda) or cutoff (c, lambda = 1/(1+c)), not both")
        if self.cutoff is not None:
            c = per_channel("cutoff", self.cutoff, m, rule="the cut-off c")
            if np.any(c <= 0):
                raise ParameterError(
                    f"cutoff c must be > 0 for every channel (lambda = 1/(1+c) < 1); got {c.tolist()}: "
                    "c = 0 gives lambda = 1, a residual root on the unit circle, so the residual never decays"
                )
            lam = 1.0 / (1.0 + c)
        else:
            lam = per_channel("lam", 0.5 if self.lam is None else self.lam, m, rule="Lambda")
        if np.any(lam >= 1):
            raise ParameterError(
                f"lam (Lambda) must be < 1 for every channel; got {lam.tolist()}: Lambda >= 1 puts a "
                "residual root on or outside the unit circle (eq 21), so the residual never decays; "
                "use e.g. Lambda = 0.5 (cut-off c = 1)"
            )
        if np.any(lam <= 0):
            raise ParameterError(f"lam (Lambda) must be > 0 (lambda = 1/(1+c), c > 0); got {lam.tolist()}")
        object.__setattr__(self, "lam", np.ascontiguousarray(lam))
        object.__setattr__(self, "cutoff", np.ascontiguousarray(1.0 / lam - 1.0))
        clip = finite_array("ratio_clip", self.ratio_clip, shape=(2,))
        if not clip[0] < clip[1]:
            raise ParameterError(f"ratio_clip must be (low, high) with low < high; got {tuple(clip)}")
        object.__setattr__(self, "ratio_clip", (float(clip[0]), float(clip[1])))

    def _correction_step(self) -> _engine.CorrectionStep:
        mapping, n, m = self._sizes()
        gamma, lam = cast(np.ndarray, self.gamma), cast(np.ndarray, self.lam)  # arrays after __post_init__
        fp = _engine.svsf_parameters(
            mapping, n, m, gamma, lam=lam, clip=self.ratio_clip, M=self._M, luen=self._luen
        )
        (lo, hi), M, luen = self.ratio_clip, self._M, self._luen

        def numpy(pr: _engine.NumpyPrior) -> tuple[np.ndarray, np.ndarray]:
            if luen is not None:
                Kg, dx = luen_correction(
                    _engine.SVSF2, pr.F, pr.e, pr.ep, pr.epp, *luen, gamma, lam, np.ones(n), lo, hi
                )
                return Kg, pr.xp + dx
            Mp = _engine.map_numpy(mapping, pr.D, pr.PCt, M, pr.e.shape[0])
            dz = pr.e - (gamma + lam) * pr.ep + gamma * lam * pr.epp
            with np.errstate(divide="ignore", invalid="ignore"):
                g = np.where(pr.e != 0.0, np.clip(dz / np.where(pr.e != 0.0, pr.e, 1.0), lo, hi), 1.0)
            return Mp * g[:, None, :], pr.xp + np.einsum("rij,rj->ri", Mp, dz)

        if luen is not None:
            return _engine.CorrectionStep("svsf2_luen", luen_second_order, fp, numpy, mapping)
        return _engine.CorrectionStep("svsf2", svsf2_correct, fp, numpy, mapping, lanes=True)


def from_settings(model: Model, settings: FilterSettings, source: str) -> SecondOrderSVSF:
    """Registry builder of ``svsf2``: gamma (default 0.1), Lambda (``cutoff_lambda``), mapping."""
    fs = settings
    gamma = 0.1 if fs.gamma is None else fs.gamma
    lam = None if fs.cutoff_lambda is None else np.asarray(fs.cutoff_lambda, dtype=float)
    return SecondOrderSVSF(model, gamma=gamma, lam=lam, mapping=fs.mapping)


@_jit.step
def svsf2_correct(fp: np.ndarray, e: np.ndarray, ep: np.ndarray, epp: np.ndarray, xp: np.ndarray,
    PCtT: np.ndarray, D: np.ndarray, L: np.ndarray, C: np.ndarray, F: np.ndarray, x: np.ndarray,
    KgT: np.ndarray, ws: tuple[np.ndarray, ...], n: int, m: int) -> int:  # fmt: skip
    """The second-order SVSF's correction (compiled step, signature of :mod:`chatterspec.filters._engine`).

    [DETC] eq (9): ``dz = e - (gamma + Lambda) e(k|k) + gamma Lambda e(k-1|k-1)``; the covariance
    gain ``g = clip(dz / e, lo, hi)`` (1 where ``e = 0``); ``x = x(k+1|k) + M dz`` (constant or
    ``cov`` map).
    """
    MpT, g, dz = ws[14], ws[15], ws[16]
    o_g, o_l, _, o_lo, o_M, _, _ = svsf_offsets(n, m)
    if not map_step(int(fp[0]), D, L, PCtT, fp, o_M, MpT, n, m):
        return NOT_PD
    lo, hi = fp[o_lo], fp[o_lo + 1]
    for i in range(m):
        gi, li = fp[o_g + i], fp[o_l + i]
        dz[i] = e[i] - (gi + li) * ep[i] + gi * li * epp[i]
        if e[i] != 0.0:
            q = dz[i] / e[i]
            g[i] = lo if q < lo else (hi if q > hi else q)
        else:
            g[i] = 1.0
    map_update_step(xp, MpT, g, dz, x, KgT, n, m)
    return 0
