"""Direct checks of numeric steps against formulas written out by hand in the test.

The compiled and numpy paths are compared with each other elsewhere (``tests/test_kernels.py``,
``tests/test_imm_kernel.py``); a bug present in both paths passes those comparisons. Each test here
recomputes a step from the papers' equations, independently of the package's code, and runs the
package on both paths (``CHATTERSPEC_JIT=0`` and, with numba installed, ``1``).
"""

from __future__ import annotations

import numpy as np
import pytest

from chatterspec import _jit
from chatterspec.filters import KalmanFilter
from chatterspec.filters.imm import IMM
from chatterspec.filters.smm_svsf import SMMSVSF
from chatterspec.filters.svsf import SVSF
from chatterspec.plants.models import LinearModel

PATHS = [
    pytest.param("0", id="numpy"),
    pytest.param(
        "1", id="compiled", marks=pytest.mark.skipif(not _jit.HAVE_NUMBA, reason="numba not installed")
    ),
]


def _sat(x: np.ndarray) -> np.ndarray:
    return np.clip(x, -1.0, 1.0)


# ------------------------------------------------------------------ SVSF, eq (4)-(12) sample by sample
def _full_model() -> LinearModel:
    A = np.array([[1.0, 0.01, 0.0], [-0.3, 0.97, 0.02], [0.05, -0.2, 0.9]])
    B = np.array([[0.0], [0.02], [0.1]])
    C = np.array([[1.0, 0.2, 0.0], [0.0, 1.0, -0.3], [0.1, 0.0, 2.0]])  # square, invertible, not I
    return LinearModel(A, B, C, 1e-4 * np.eye(3), 1e-2 * np.eye(3), 0.01)


@pytest.mark.parametrize("jit", PATHS)
def test_sat_svsf_full_measurement_is_eq_8_by_hand(jit: str, monkeypatch: pytest.MonkeyPatch) -> None:
    """Eq (4)-(8), (12): K = C^-1 (|e(k+1|k)| + gamma |e(k|k)|) o sat(e(k+1|k) / psi), per sample."""
    monkeypatch.setenv("CHATTERSPEC_JIT", jit)
    m = _full_model()
    runs, T, gamma = 4, 60, 0.3
    psi = np.array([0.05, 0.08, 0.12])
    rng = np.random.default_rng(3)
    z = np.cumsum(rng.normal(scale=0.05, size=(runs, T, 3)), axis=1)
    u = rng.uniform(-1, 1, size=(T, 1))
    x0 = rng.normal(scale=0.1, size=(runs, 3))  # a non-zero e(0|0), so the gamma term acts from the start
    f = SVSF(m, psi=psi, gamma=gamma)
    state = f.initialize(z[:, 0], x0=x0)
    _, out = f.update(state, z[:, 1:], u[:-1], store={"x_post", "e_post"})

    Cinv = np.linalg.inv(m.C)
    x, ebar = x0.copy(), z[:, 0] - x0 @ m.C.T
    inside = outside = 0
    for k in range(T - 1):
        xp = x @ m.A.T + u[k] @ m.B.T  # eq (4)
        e = z[:, k + 1] - xp @ m.C.T  # eq (6)
        gain = (np.abs(e) + gamma * np.abs(ebar)) * _sat(e / psi)  # eq (8), output space
        x = xp + gain @ Cinv.T  # eq (8) C^-1, eq (12)
        ebar = z[:, k + 1] - x @ m.C.T  # eq (7) at k + 1
        inside += int(np.sum(np.abs(e) < psi))
        outside += int(np.sum(np.abs(e) > psi))
        np.testing.assert_allclose(out.e_prior[:, k], e, rtol=1e-10, atol=1e-13, err_msg=f"e(k+1|k), k={k}")
        np.testing.assert_allclose(out.x_post[:, k], x, rtol=1e-10, atol=1e-13, err_msg=f"x(k+1|k+1), k={k}")
        np.testing.assert_allclose(
            out.e_post[:, k], ebar, rtol=1e-9, atol=1e-13, err_msg=f"e(k+1|k+1), k={k}"
        )
    assert inside > 50 and outside > 50  # both branches of sat are exercised


@pytest.mark.parametrize("jit", PATHS)
def test_sat_svsf_reduced_order_is_eq_9_to_11_by_hand(jit: str, monkeypatch: pytest.MonkeyPatch) -> None:
    """Fig 2's form (C = [1 0], so T = I and Phi = A): eq (9) for x1, eq (10)-(11) for x2."""
    monkeypatch.setenv("CHATTERSPEC_JIT", jit)
    w0, dt = 2 * np.pi * 2.0, 1e-3
    A = np.array([[1.0, dt], [-dt * w0**2, 1.0]])
    m = LinearModel(A, np.array([[0.0], [0.1]]), np.array([[1.0, 0.0]]), np.diag([1e-10, 1e-8]), [[1e-8]], dt)
    runs, T, gamma = 3, 80, 0.1
    psi_u, psi_l = 3e-4, 0.3
    rng = np.random.default_rng(4)
    z = np.cumsum(rng.normal(scale=3e-4, size=(runs, T, 1)), axis=1)
    u = np.ones((T, 1))
    x0 = np.column_stack([z[:, 0, 0] + 1e-4, rng.normal(scale=0.05, size=runs)])
    f = SVSF(m, psi=[psi_u, psi_l], gamma=gamma)
    state = f.initialize(z[:, 0], x0=x0)
    _, out = f.update(state, z[:, 1:], u[:-1], store={"x_post", "e_lower"})

    P = 1.0 / A[0, 1]  # Phi12^-1
    L = A[1, 1] * P  # Phi22 Phi12^-1
    x, ebar = x0.copy(), z[:, 0, 0] - x0[:, 0]
    sat_l = 0
    for k in range(T - 1):
        xp = x @ A.T + u[k] @ m.B.T
        e = z[:, k + 1, 0] - xp[:, 0]
        k_u = (np.abs(e) + gamma * np.abs(ebar)) * _sat(e / psi_u)  # eq (9)
        le = L * e
        k_l = (np.abs(le) + gamma * np.abs(P * ebar)) * _sat(le / psi_l)  # eq (10)-(11)
        x = xp + np.column_stack([k_u, k_l])
        ebar = z[:, k + 1, 0] - x[:, 0]
        sat_l += int(np.sum(np.abs(le) > psi_l))
        np.testing.assert_allclose(out.e_lower[:, k, 0], le, rtol=1e-10, err_msg=f"k={k}")
        np.testing.assert_allclose(out.x_post[:, k], x, rtol=1e-10, atol=1e-14, err_msg=f"k={k}")
    assert 0 < sat_l < runs * (T - 1)  # the unmeasured switching term is inside and outside its layer


# ------------------------------------------------------------------ IMM, [IMM] eq 15-33 (corrected)
def _imm_modes() -> list[LinearModel]:
    dt = 0.01
    out = []
    for f0, zeta, q in ((1.0, 0.05, 1e-4), (3.0, 0.2, 4e-4), (6.0, 0.5, 1e-3)):
        w = 2 * np.pi * f0
        A = np.array([[1.0, dt], [-dt * w * w, 1.0 - 2 * dt * zeta * w]])
        out.append(
            LinearModel(A, np.array([[0.0], [dt]]), np.array([[1.0, 0.0]]), q * np.eye(2), [[4e-4]], dt)
        )
    return out


def _reference_imm(models, pi, mu0, x0, P0, z, u, svsf=None):  # type: ignore[no-untyped-def]
    """[IMM] eq 18-33 as corrected (c_j normalizer, factor 1/2 in the spread), Joseph form.

    Mode filters: the Kalman filter, or with ``svsf = (psi, gamma)`` the SVSF with covariance ([SMM]
    eq 2.5 in its division-free form, the covariance mapping M = P C^T (C P C^T)^-1 for C = [1 0]),
    whose e(k|k) after mixing is the residual of the mode's mixed estimate, z(k) - C x_0j
    (``docs/design.md`` I4), and 0 at the first sample.
    """
    r, n = len(models), x0.shape[0]
    runs, T, _ = z.shape
    xs = np.broadcast_to(x0, (runs, r, n)).copy()
    Ps = np.broadcast_to(P0, (runs, r, n, n)).copy()
    mu = np.broadcast_to(mu0, (runs, r)).copy()
    X, MU = np.empty((runs, T, n)), np.empty((runs, T, r))
    P_out, spread = np.empty((runs, T, n, n)), np.empty((runs, T, n, n))
    for q in range(runs):
        for k in range(T):
            c = pi.T @ mu[q]  # (19) c_j = sum_i pi_ij mu_i
            w = pi * mu[q][:, None] / c[None, :]  # (18) mu_{i|j}
            new_x, new_P, lik = np.empty((r, n)), np.empty((r, n, n)), np.empty(r)
            for j, mdl in enumerate(models):
                x0j = w[:, j] @ xs[q]  # (20)
                d0 = xs[q] - x0j
                P0j = sum(w[i, j] * (Ps[q, i] + np.outer(d0[i], d0[i])) for i in range(r))  # (21)
                xp = mdl.A @ x0j + mdl.B @ u[k]  # (22)
                Pp = mdl.A @ P0j @ mdl.A.T + mdl.Q  # (23)
                e = z[q, k] - mdl.C @ xp  # (24)
                S = mdl.C @ Pp @ mdl.C.T + mdl.R  # (25)
                if svsf is None:
                    K = Pp @ mdl.C.T @ np.linalg.inv(S)
                else:
                    psi, gamma = svsf
                    ebar = np.zeros(1) if k == 0 else z[q, k - 1] - mdl.C @ x0j  # I4
                    kappa = (np.abs(e) + gamma * np.abs(ebar)) / np.maximum(np.abs(e), psi)
                    M = Pp @ mdl.C.T @ np.linalg.inv(mdl.C @ Pp @ mdl.C.T)
                    K = M * kappa  # M diag(kappa)
                new_x[j] = xp + K @ e
                IKC = np.eye(n) - K @ mdl.C
                new_P[j] = IKC @ Pp @ IKC.T + K @ mdl.R @ K.T  # Joseph form in place of (28)
                quad = e @ np.linalg.solve(S, e)
                lik[j] = np.exp(-0.5 * quad) / np.sqrt(np.linalg.det(2 * np.pi * S))  # (29)
            mu[q] = c * lik / np.sum(c * lik)  # (30)
            xs[q], Ps[q] = new_x, new_P
            x = mu[q] @ new_x  # (31)
            d = new_x - x
            sp = sum(mu[q, j] * np.outer(d[j], d[j]) for j in range(r))  # (33) with the factor 1/2
            X[q, k], MU[q, k], spread[q, k] = x, mu[q], sp
            P_out[q, k] = sum(mu[q, j] * new_P[j] for j in range(r)) + sp  # (32)
    return X, MU, P_out, spread


def _imm_data(models, runs: int = 3, T: int = 120):  # type: ignore[no-untyped-def]
    rng = np.random.default_rng(5)
    u = rng.uniform(-1, 1, size=(T, 1))
    x = np.zeros((runs, 2))
    zs = []
    for k in range(T):  # the true plant switches 1 Hz -> 3 Hz -> 6 Hz
        mdl = models[min(k // 40, 2)]
        x = x @ mdl.A.T + u[k] @ mdl.B.T + rng.normal(scale=np.sqrt(1e-4), size=(runs, 2))
        zs.append(x[:, :1] + rng.normal(scale=0.02, size=(runs, 1)))
    return np.stack(zs, axis=1), u


PI3 = np.array([[0.90, 0.07, 0.03], [0.20, 0.70, 0.10], [0.05, 0.15, 0.80]])  # asymmetric
MU0 = np.array([0.6, 0.3, 0.1])


@pytest.mark.parametrize("jit", PATHS)
@pytest.mark.parametrize("kind", ["kf", "svsf-cov"])
def test_imm_equals_an_independent_imm_with_distinct_modes(
    kind: str, jit: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Combined estimate, mode probabilities and combined covariance against the written-out cycle,
    with modes that really differ (1 / 3 / 6 Hz) and an asymmetric transition matrix, so that the
    spread terms of eq 21 and eq 32-33, the mixing weights of eq 18 and (SVSF-type modes) the
    residual of the mixed estimate all matter."""
    from chatterspec.filters import SVSFCov

    monkeypatch.setenv("CHATTERSPEC_JIT", jit)
    models = _imm_modes()
    z, u = _imm_data(models)
    x0, P0 = np.array([0.0, 0.0]), np.diag([0.01, 0.1])
    psi, gamma = 0.03, 0.4
    svsf = None if kind == "kf" else (psi, gamma)
    bank = [KalmanFilter(m) if kind == "kf" else SVSFCov(m, psi=psi, gamma=gamma) for m in models]
    out = IMM(bank, PI3, mu0=MU0).run(z, u, x0=x0, P0=P0, store={"P_post"})
    X, MU, P, spread = _reference_imm(models, PI3, MU0, x0, P0, z, u, svsf)
    np.testing.assert_allclose(out.mu, MU, rtol=1e-7, atol=1e-12)
    np.testing.assert_allclose(out.x_post, X, rtol=1e-7, atol=1e-12)
    np.testing.assert_allclose(out.P_post, P, rtol=1e-7, atol=1e-14)
    # the check has teeth: the modes disagree, so the spread is a visible part of P
    assert np.max(spread[..., 1, 1] / P[..., 1, 1]) > 0.05
    assert np.ptp(MU, axis=1).min() > 0.1  # every mode's probability moves (range over time)


# ------------------------------------------------------- SMM-SVSF weight floor ([SMM] Table 1 step 3)
@pytest.mark.parametrize("reading", ["table1", "bank"])
def test_smm_weight_floor_is_applied_and_active(reading: str) -> None:
    """With a mode that the data rule out, its weight sits at the default floor (1e-3, renormalized)
    instead of underflowing towards 0, and every weight vector sums to 1."""
    # two of the three outputs: the compiled SMM loop of the other 3-state, 2-output banks of the tests
    # (tests/test_multiple_model.py, tests/test_one_sample.py) instead of a loop of its own
    full = _full_model()
    mdl = LinearModel(full.A, full.B, full.C[[0, 2]], full.Q, full.R[:2, :2], full.dt)
    wrong = LinearModel(mdl.A, 20.0 * mdl.B, mdl.C, mdl.Q, mdl.R, mdl.dt)  # a 20x input gain
    rng = np.random.default_rng(6)
    runs, T = 2, 150
    u = np.ones((T, 1))
    x = np.zeros((runs, 3))
    zs = []
    for k in range(T):
        x = mdl.transition(x, u[k]) + rng.normal(scale=1e-2, size=(runs, 3))
        zs.append(x @ mdl.C.T + rng.normal(scale=0.1, size=(runs, 2)))
    z = np.stack(zs, axis=1)
    smm = SMMSVSF([mdl, wrong], psi=0.5, reading=reading)
    floor = smm.weight_floor
    assert floor == pytest.approx(1e-3)
    out = smm.run(z, u, x0=np.zeros(3), P0=np.eye(3))
    np.testing.assert_allclose(out.mu.sum(axis=-1), 1.0, rtol=1e-12)
    # after flooring, renormalization divides by at most 1 + (r - 1) floor
    assert np.all(out.mu >= floor / (1 + floor) * (1 - 1e-12)), out.mu.min()
    at_floor = np.isclose(out.mu[..., 1], floor / (1 + floor), rtol=1e-6)
    assert at_floor[:, 20:].mean() > 0.9  # the wrong mode's weight is held by the floor most of the time


# ------------------------------------------------------------------ spectral verdict and severity
@pytest.mark.parametrize("jit", PATHS)
def test_detect_spectrum_verdict_and_severity_by_hand(jit: str, monkeypatch: pytest.MonkeyPatch) -> None:
    """``peak_ratio = max S / threshold``, ``most_significant_hz`` its bin, ``excess_power =
    sum (S - E[S]) / sum E[S]`` and ``peak_hz`` = the largest excess among the bins over the threshold
    (over all tested bins when none is over), all over the tested bins only."""
    monkeypatch.setenv("CHATTERSPEC_JIT", jit)
    from chatterspec.detection.spectral import periodogram_freqs
    from chatterspec.detection.thresholds import exact_threshold
    from chatterspec.detection.verdicts import detect_spectrum
    from chatterspec.plants.models import second_order

    model = second_order(10.0, 0.1, R=np.diag([1e-6, 1e-4]))
    N = 400
    f = periodogram_freqs(N, model.dt)
    thr = exact_threshold(model, f, N, 1e-3)
    E, T, tested = thr.expected, thr.values, thr.tested
    rng = np.random.default_rng(8)
    power = E * rng.exponential(size=(5, f.size, 2))
    # record 0: a bin over the threshold where E[S] is small, and a bin just below it where E[S] is
    # the largest: the largest excess overall is not the peak the rule reports
    lo_e, hi_e = 5, int(np.argmax(np.where(tested, E[:, 1], -np.inf)))
    power[0, lo_e, 1] = 3.0 * T[lo_e, 1]
    power[0, hi_e, 1] = 0.99 * T[hi_e, 1]
    assert power[0, hi_e, 1] - E[hi_e, 1] > power[0, lo_e, 1] - E[lo_e, 1]
    power[1, 0, :] = 1e6 * T[0]  # an enormous DC bin is not tested
    out = detect_spectrum(power, thr)

    S, Et, Tt, ft = power[:, tested], E[tested], T[tested], f[tested]
    ratio = S / Tt
    k = np.argmax(ratio, axis=1)
    np.testing.assert_allclose(out.peak_ratio, np.max(ratio, axis=1), rtol=1e-14)
    np.testing.assert_array_equal(out.most_significant_hz, ft[k])
    np.testing.assert_array_equal(out.detected, np.max(ratio, axis=1) > 1.0)
    np.testing.assert_allclose(out.excess_power, (S - Et).sum(axis=1) / Et.sum(axis=0), rtol=1e-12)
    over = ratio > 1.0
    ex = S - Et
    want = np.where(over.any(axis=1), np.argmax(np.where(over, ex, -np.inf), axis=1), np.argmax(ex, axis=1))
    np.testing.assert_array_equal(out.peak_hz, ft[want])
    assert out.peak_hz[0, 1] == f[lo_e] and out.detected[0, 1]
    np.testing.assert_allclose(out.dc_ratio, power[:, 0] / T[0], rtol=1e-14)
