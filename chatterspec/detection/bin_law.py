"""The law of one periodogram bin, ``Y = l1 Z1^2 + l2 Z2^2`` (a weighted sum of two chi2(1)).

Its survival function, density and inverse (:func:`weighted_chi2_sf`, :func:`weighted_chi2_pdf`,
:func:`weighted_chi2_isf`) give the ``exact`` thresholds of :mod:`chatterspec.detection.thresholds`
(which re-exports them); ``l1 = l2`` is the chi2(2)/2 law of Lemma 2.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
import scipy.special

from ..errors import ParameterError

__all__ = ["weighted_chi2_isf", "weighted_chi2_pdf", "weighted_chi2_sf"]


def _chi2_isf(p: npt.ArrayLike, dof: npt.ArrayLike) -> np.ndarray:
    """Inverse survival function of the chi-squared law: ``scipy.stats.chi2.isf(p, dof)``.

    The same function underneath (``scipy.special.chdtri``), without importing :mod:`scipy.stats`
    (a few hundred ms at every command start).
    """
    return scipy.special.chdtri(dof, p)


# ---------------------------------------------------------------------------
# Law of one bin: Y = l1 Z1^2 + l2 Z2^2 (weighted sum of two chi2(1))
# ---------------------------------------------------------------------------
_GL_X, _GL_W = np.polynomial.legendre.leggauss(64)
_ERFC_CUT = 12.0  # erfc(12) ~ 1e-64: the integrand beyond is negligible


def _eigen_pair(l1: npt.ArrayLike, l2: npt.ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    a = np.asarray(l1, dtype=float)
    b = np.asarray(l2, dtype=float)
    if not (np.all(np.isfinite(a)) and np.all(np.isfinite(b))) or np.any(a < 0) or np.any(b < 0):
        raise ParameterError("weights l1, l2 must be finite and >= 0")
    return np.maximum(a, b), np.minimum(a, b)


def _sf_unit(x: np.ndarray, r: np.ndarray) -> np.ndarray:
    """``P(Z1^2 + r Z2^2 > x)`` for ``0 <= r <= 1``, ``x >= 0`` (arrays of one shape).

    Conditioning on ``Z1``: ``erfc(z1 / sqrt 2) + int_{|z| < z1} phi(z) erfc(sqrt((x - z^2) / (2 r))) dz``
    with ``z1 = sqrt(x)``; the substitution ``z = z1 cos s`` gives
    ``2 z1 int_0^{pi/2} phi(z1 cos s) erfc(K sin s) sin s ds``, ``K = sqrt(x / (2 r))``, an entire
    integrand, cut where ``K sin s > 12`` and integrated by 64-point Gauss-Legendre (relative error
    ~1e-15 against direct quadrature of the density, whatever ``r``).
    """
    z1 = np.sqrt(x)
    first = scipy.special.erfc(z1 / np.sqrt(2.0))
    pos = r > 0
    with np.errstate(divide="ignore", invalid="ignore"):
        K = np.where(pos, np.sqrt(x / (2.0 * np.where(pos, r, 1.0))), np.inf)
    Ks = np.where(np.isfinite(K) & (K > 0), K, 1.0)
    smax = np.where(K > _ERFC_CUT, np.arcsin(np.minimum(1.0, _ERFC_CUT / Ks)), 0.5 * np.pi)
    sn = smax[..., None] * (0.5 * (_GL_X + 1.0))
    sin_s = np.sin(sn)
    integrand = (
        np.exp(-0.5 * (z1[..., None] * np.cos(sn)) ** 2)
        * scipy.special.erfc(np.where(pos, Ks, 0.0)[..., None] * sin_s)
        * sin_s
    )
    second = z1 * smax * (integrand @ _GL_W) / np.sqrt(2.0 * np.pi)
    return first + np.where(pos & (x > 0), second, 0.0)


def _pdf_unit(x: np.ndarray, r: np.ndarray) -> np.ndarray:
    """Density of ``Z1^2 + r Z2^2`` at ``x > 0``: ``exp(-x/2) I0(x (1 - r) / (4 r)) e^{...} / (2 sqrt r)``."""
    pos = r > 0
    rs = np.where(pos, r, 1.0)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        gen = np.exp(-0.5 * x) * scipy.special.i0e(x * (1.0 - rs) / (4.0 * rs)) / (2.0 * np.sqrt(rs))
        chi1 = np.exp(-0.5 * x) / np.sqrt(2.0 * np.pi * x)
    return np.where(pos, gen, chi1)


def weighted_chi2_sf(t: npt.ArrayLike, l1: npt.ArrayLike, l2: npt.ArrayLike) -> np.ndarray:
    """Survival function ``P(l1 Z1^2 + l2 Z2^2 > t)``, ``Z1, Z2`` iid standard normal (broadcasting).

    The exact law of a periodogram or frame bin of Gaussian data (see
    :func:`chatterspec.detection.spectral.periodogram_eigenvalues`). ``l1 = l2 = l`` gives
    ``exp(-t / (2 l))`` (``l chi2(2)``), ``l2 = 0`` gives ``l1 chi2(1)``. Computed by a
    one-dimensional integral (Gauss-Legendre, relative error ~1e-15) of non-negative terms,
    so it is accurate far in the tail.

    Parameters
    ----------
    t : array_like
        Thresholds (any real; ``sf = 1`` for ``t <= 0``).
    l1, l2 : array_like
        Non-negative weights (their order does not matter).

    See Also
    --------
    weighted_chi2_pdf : its density.
    weighted_chi2_isf : its inverse (the threshold at a level).
    """
    a, b = _eigen_pair(l1, l2)
    t = np.asarray(t, dtype=float)
    t, a, b = np.broadcast_arrays(t, a, b)
    out = np.ones(t.shape)
    ok = (t > 0) & (a > 0)
    if np.any(ok):
        out[ok] = _sf_unit(t[ok] / a[ok], b[ok] / a[ok])
    return out


def weighted_chi2_pdf(t: npt.ArrayLike, l1: npt.ArrayLike, l2: npt.ArrayLike) -> np.ndarray:
    """Density of ``l1 Z1^2 + l2 Z2^2`` at ``t > 0`` (0 for ``t <= 0``; requires ``max(l1, l2) > 0``).

    See Also
    --------
    weighted_chi2_sf : the survival function.
    weighted_chi2_isf : the inverse survival function.
    """
    a, b = _eigen_pair(l1, l2)
    t = np.asarray(t, dtype=float)
    t, a, b = np.broadcast_arrays(t, a, b)
    if np.any(a <= 0):
        raise ParameterError("weighted_chi2_pdf needs max(l1, l2) > 0")
    out = np.zeros(t.shape)
    ok = t > 0
    out[ok] = _pdf_unit(t[ok] / a[ok], b[ok] / a[ok]) / a[ok]
    return out


def weighted_chi2_isf(
    p: npt.ArrayLike, l1: npt.ArrayLike, l2: npt.ArrayLike, rtol: float = 1e-10
) -> np.ndarray:
    """Inverse survival function of ``l1 Z1^2 + l2 Z2^2``: ``t`` with ``P(Y > t) = p`` (broadcasting).

    Safeguarded Newton iteration on ``log sf`` (vectorized over every bin and channel)
    inside the bracket ``l1 chi2.isf(p, 1) <= t <= l1 chi2.isf(p, 2)`` (``l1 Z1^2 <= Y <=
    l1 (Z1^2 + Z2^2)``), to relative accuracy ``rtol``. ``l2 = 0`` is exactly
    ``l1 chi2.isf(p, 1)``; ``l1 = l2 = 0`` gives 0.

    Parameters
    ----------
    p : array_like
        Exceedance probabilities in (0, 1).
    l1, l2 : array_like
        Non-negative weights (their order does not matter).
    rtol : float
        Relative tolerance on ``t``.

    See Also
    --------
    weighted_chi2_sf : the survival function it inverts.
    weighted_chi2_pdf : the density.
    """
    a, b = _eigen_pair(l1, l2)
    p = np.asarray(p, dtype=float)
    if not np.all((p > 0) & (p < 1)):
        raise ParameterError("p must lie in the open interval (0, 1)")
    p, a, b = np.broadcast_arrays(p, a, b)
    out = np.zeros(p.shape)
    ok = a > 0
    if not np.any(ok):
        return out
    pv, r = p[ok], b[ok] / a[ok]
    lo = _chi2_isf(pv, 1)
    hi = _chi2_isf(pv, 2)
    # start from the Welch-Satterthwaite approximation, clipped into the bracket
    c = (1.0 + r * r) / (1.0 + r)
    x = np.clip(c * _chi2_isf(pv, (1.0 + r) ** 2 / (1.0 + r * r)), lo, hi)
    x = np.where(r > 0, x, lo)
    act = r > 0
    logp = np.log(pv)
    for _ in range(200):
        if not np.any(act):
            break
        xa, ra = x[act], r[act]
        sf = _sf_unit(xa, ra)
        h = np.log(sf) - logp[act]
        lo_a = np.where(h > 0, xa, lo[act])  # sf too large: the quantile is above x
        hi_a = np.where(h > 0, hi[act], xa)
        with np.errstate(divide="ignore", invalid="ignore"):
            step = h * sf / _pdf_unit(xa, ra)  # Newton: x - h / h', h' = -pdf / sf
        xn = xa + step
        conv = np.isfinite(step) & (np.abs(step) <= rtol * xa)  # converged (may sit on the bracket)
        bad = ~np.isfinite(xn) | (xn <= lo_a) | (xn >= hi_a)
        xn = np.where(conv | (h == 0), np.where(h == 0, xa, xn), np.where(bad, 0.5 * (lo_a + hi_a), xn))
        done = conv | (h == 0) | (hi_a - lo_a <= rtol * xa)
        lo[act], hi[act], x[act] = lo_a, hi_a, xn
        idx = np.flatnonzero(act)
        act[idx[done]] = False
    out[ok] = x * a[ok]
    return out
