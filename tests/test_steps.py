"""Every compiled step against an independent hand formula, sample by sample.

The loops of the package are built from these steps (see chatterspec._jit): a wrong step is wrong
on every path that calls it, so comparing compiled with numpy paths cannot see it. Each test here
writes the paper's equation with numpy vector operations and compares one call of the step.
Tolerance: 1e-12 relative to the size of the terms (the step sums in a fixed loop order, numpy in
BLAS's; the difference is a few ulps); the deliberate errors these tests are for (a factor 2 on
psi, a dropped term, a transposed matrix) change the result by far more.
"""

from __future__ import annotations

import numpy as np
import pytest

from chatterspec.filters import _engine, bank
from chatterspec.filters.bank import combine, log_gaussian, normalize_log_weights
from chatterspec.filters.kalman import _KF_STEP
from chatterspec.filters.svsf_recursion import (
    closed_form_step,
    copy_pair_step,
    matvec_step,
    rows_times_step,
    svsf_step,
)
from chatterspec.plants import eha4 as eha4_mod
from chatterspec.plants import steps

RTOL = 1e-12


def close(a: np.ndarray, b: np.ndarray, scale: np.ndarray | float | None = None) -> None:
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    s = np.maximum(np.abs(b), 1e-300) if scale is None else scale
    assert np.all(np.abs(a - b) <= RTOL * s), (a, b)


def sat(v: np.ndarray) -> np.ndarray:
    return np.clip(v, -1.0, 1.0)


@pytest.mark.parametrize("switching", ["sat", "sgn"])
def test_svsf_step_full_measurement_is_eq_4_to_12(switching: str) -> None:
    """Eq (4), (6), (8), (12) with C = I: both inside (|e| < psi) and outside the boundary layer."""
    rng = np.random.default_rng(1)
    n = m = 3
    Phi = np.eye(3) + 0.05 * rng.standard_normal((3, 3))
    y, ep = rng.standard_normal(3), 0.01 * rng.standard_normal(3)
    gu, z = 0.1 * rng.standard_normal(3), rng.standard_normal(3)
    gamma = 0.3
    yp_ref = Phi @ y + gu  # eq (4)
    e = z - yp_ref  # eq (6)
    psi = np.abs(e) * np.array([2.0, 0.5, 3.0])  # channels 0, 2 inside the layer, 1 outside
    sw = sat(e / psi) if switching == "sat" else np.sign(e)
    K = (np.abs(e) + gamma * np.abs(ep)) * sw  # eq (8)
    y_ref = yp_ref.copy()
    y_ref[:m] += K  # eq (12)
    ep_ref = z - y_ref  # e(k+1|k+1)
    inv_psi = 1.0 / psi if switching == "sat" else np.empty(0)
    yy, ee = y.copy(), ep.copy()
    yp, e_out, le = np.empty(n), np.empty(m), np.empty(0)
    e2 = np.empty((0, m))
    svsf_step(
        z,
        gu,
        np.ascontiguousarray(Phi.T),
        e2,
        e2,
        inv_psi,
        gamma,
        yy,
        ee,
        yp,
        e_out,
        le,
        n,
        m,
        0,
        switching == "sat",
    )
    close(yp, yp_ref, np.abs(Phi) @ np.abs(y) + np.abs(gu))
    close(e_out, e, np.abs(z) + np.abs(yp_ref))
    close(yy, y_ref, np.abs(z) + np.abs(yp_ref))
    close(ee, ep_ref, np.abs(z) + np.abs(yp_ref))


def test_svsf_step_reduced_order_is_eq_9_to_12() -> None:
    """Luenberger's reduced-order form, n = 2, m = 1, in measurement-aligned coordinates."""
    n, m = 2, 1
    Phi = np.array([[1.0, 0.01], [-0.3, 0.97]])
    Phi12, Phi22 = Phi[:m, m:], Phi[m:, m:]
    P = np.linalg.inv(Phi12)
    L = Phi22 @ P
    y, ep = np.array([0.2, -1.0]), np.array([0.003])
    gu, z = np.array([0.0, 0.01]), np.array([0.21])
    gamma = 0.2
    yp_ref = Phi @ y + gu
    e = z - yp_ref[:m]
    Le = L @ e
    psi = np.array([abs(e[0]) * 2.0, abs(Le[0]) * 0.5])  # measured inside, unmeasured outside
    Kl = (np.abs(Le) + gamma * np.abs(P @ ep)) * sat(Le / psi[1:])  # eq (10)
    Ku = (np.abs(e) + gamma * np.abs(ep)) * sat(e / psi[:1])  # eq (9)
    y_ref = yp_ref + np.concatenate([Ku, Kl])  # eq (12)
    yy, ee = y.copy(), ep.copy()
    yp, e_out, le = np.empty(n), np.empty(m), np.empty(1)
    svsf_step(
        z, gu, np.ascontiguousarray(Phi.T), L, P, 1.0 / psi, gamma, yy, ee, yp, e_out, le, n, m, 1, True
    )
    scale = np.abs(Phi) @ np.abs(y) + np.abs(gu) + np.abs(np.concatenate([z, Le]))
    close(yy, y_ref, scale)
    close(le, Le, np.abs(L) @ np.abs(e))
    close(ee, z - y_ref[:m], scale[:m])


def test_closed_form_step_is_eq_23() -> None:
    rng = np.random.default_rng(3)
    Phi = rng.standard_normal((3, 3))
    z1, z0, gu = rng.standard_normal(3), rng.standard_normal(3), rng.standard_normal(3)
    ref = z1 - Phi @ z0 - gu  # e(k+1|k) = z(k+1) - Phi z(k) - G u(k)
    got = [closed_form_step(i, z1[i], gu[i], np.ascontiguousarray(Phi.T), z0, 3) for i in range(3)]
    close(got, ref, np.abs(z1) + np.abs(Phi) @ np.abs(z0) + np.abs(gu))


def test_rows_times_and_matvec_steps() -> None:
    rng = np.random.default_rng(4)
    M, a = rng.standard_normal((2, 3)), rng.standard_normal(2)
    out = np.empty(3)
    rows_times_step(a, M, out, 2, 3)
    close(out, a @ M, np.abs(a) @ np.abs(M))
    S, v = rng.standard_normal((3, 3)), rng.standard_normal(3)
    matvec_step(S, v, out, 3, 3)
    close(out, S @ v, np.abs(S) @ np.abs(v))
    a2, b2 = np.full(3, np.nan), np.full(3, np.nan)
    copy_pair_step(v, a, a2, b2, 3, 2)  # all of a, the first two entries of b2
    np.testing.assert_array_equal(a2, v)
    np.testing.assert_array_equal(b2[:2], a)
    assert np.isnan(b2[2])


def test_linear_plant_steps_are_eq_1_and_2() -> None:
    rng = np.random.default_rng(5)
    A, B, C = rng.standard_normal((1, 3, 3)), rng.standard_normal((3, 2)), rng.standard_normal((1, 2, 3))
    Lq, Lr = np.tril(rng.standard_normal((1, 3, 3))), np.tril(rng.standard_normal((1, 2, 2)))
    x, v, w, u = (
        rng.standard_normal(3),
        rng.standard_normal(3),
        rng.standard_normal(2),
        rng.standard_normal(2),
    )
    for diag in (False, True):
        if diag:
            Lq, Lr = Lq * np.eye(3), Lr * np.eye(2)
        flags = np.array([[diag, diag]])
        z, xn = np.empty(2), np.empty(3)
        steps.measure_step(0, x, w, C, Lr, flags, z, 3, 2)
        close(z, C[0] @ x + Lr[0] @ w, np.abs(C[0]) @ np.abs(x) + np.abs(Lr[0]) @ np.abs(w))
        steps.advance_step(0, x, B @ u, v, A, Lq, flags, xn, 3)
        scale = np.abs(A[0]) @ np.abs(x) + np.abs(B) @ np.abs(u) + np.abs(Lq[0]) @ np.abs(v)
        close(xn, A[0] @ x + B @ u + Lq[0] @ v, scale)
    prm = steps.parameters(A[0], B)
    xp, F = np.empty(3), np.empty((3, 3))
    steps.predict_step(prm, x, u, xp, 3, 2)
    close(xp, A[0] @ x + B @ u, np.abs(A[0]) @ np.abs(x) + np.abs(B) @ np.abs(u))
    steps.jacobian_step(prm, x, u, F, 3, 2)
    np.testing.assert_array_equal(F, A[0])


def test_eha4_steps_are_eq_4_1_to_4_5_and_their_jacobian() -> None:
    """The corrected eq (4.1)-(4.5) from the physical parameters, and a central-difference Jacobian."""
    p = eha4_mod.eha4_mode_parameters("leak-major")
    T = 1e-3
    A_E, M, V0, be, L = p["piston_area"], p["mass"], p["volume"], p["bulk_modulus"], p["leakage"]
    a1, a2, a3, Dp, QL0 = p["a1"], p["a2"], p["a3"], p["pump_displacement"], p["flow_offset"]
    prm = eha4_mod.coefficient_vector(eha4_mod._coefficients(T, p))
    for x in (np.array([0.01, 0.02, -0.5, 3e5]), np.array([0.0, -0.01, 0.3, -2e5])):
        w = 40.0
        x1, x2, x3, x4 = x
        u = Dp * w - np.sign(x4) * QL0  # (4.5)
        x3n = (
            (1 - T * (a2 * V0 + M * be * L) / (M * V0)) * x3
            - T * (A_E**2 + a2 * L) * be / (M * V0) * x2
            - T * (2 * a1 * V0 * x2 * x3 + be * L * (a1 * x2**2 + a3)) / (M * V0) * np.sign(x2)
            + T * A_E * be / (M * V0) * u
        )  # (4.3), corrected
        ref = np.array(
            [x1 + T * x2, x2 + T * x3, x3n, (a2 * x2 + (a1 * x2**2 + a3) * np.sign(x2) + M * x3) / A_E]
        )
        xp = np.empty(4)
        eha4_mod.predict_step(prm, x, np.array([w]), xp, 4, 1)
        np.testing.assert_allclose(xp, ref, rtol=1e-10, atol=1e-18)
        F = np.empty((4, 4))
        eha4_mod.jacobian_step(prm, x, np.array([w]), F, 4, 1)
        num = np.empty((4, 4))
        for j in range(4):
            h = 1e-7 * max(abs(x[j]), 1e-3)
            hi, lo = np.empty(4), np.empty(4)
            eha4_mod.predict_step(prm, x + h * np.eye(4)[j], np.array([w]), hi, 4, 1)
            eha4_mod.predict_step(prm, x - h * np.eye(4)[j], np.array([w]), lo, 4, 1)
            num[:, j] = (hi - lo) / (2 * h)
        num[:, 3] = 0.0  # x4 enters only through sgn(x4): sgn' = 0 by convention
        np.testing.assert_allclose(F, num, rtol=1e-5, atol=1e-9)


def _one_sample(correct, x, P, ep, epp, z, A, B, u, C, Q, R):  # type: ignore[no-untyped-def]
    """One sample of the compiled covariance loop (a linear plant), all outputs kept."""
    plant = type("Plant", (), {})()
    plant.name, plant.predict, plant.jacobian = (
        "linear",
        steps.predict_step,
        steps.jacobian_step,
    )
    plant.constant_jacobian, plant.parameters = True, steps.parameters(A, B)
    xs, Ps, eps, epps = x[None].copy(), P[None].copy(), ep[None].copy(), epp[None].copy()
    out = _engine.cov_loop(
        correct, plant, xs, Ps, eps, epps, z[None, None], u[None, None], C, Q, R, frozenset(_engine.FIELDS)
    )
    return xs[0], Ps[0], eps[0], epps[0], out


def _system(m: int = 2):  # type: ignore[no-untyped-def]
    rng = np.random.default_rng(6)
    n = 3
    A = np.eye(n) + 0.1 * rng.standard_normal((n, n))
    B = rng.standard_normal((n, 1))
    C = np.eye(n)[:m] if m < n else np.eye(n)
    G = rng.standard_normal((n, n))
    P = G @ G.T + np.eye(n)
    Q, R = 0.01 * np.eye(n), 0.1 * np.eye(m)
    x, u = rng.standard_normal(n), np.array([0.3])
    z = C @ (A @ x + B @ u) + rng.standard_normal(m)
    ep, epp = 0.05 * rng.standard_normal(m), 0.02 * rng.standard_normal(m)
    return A, B, C, Q, R, P, x, u, z, ep, epp


def test_kalman_sample_is_the_textbook_step() -> None:
    A, B, C, Q, R, P, x, u, z, ep, epp = _system()
    xn, Pn, epn, eppn, out = _one_sample(_KF_STEP, x, P, ep, epp, z, A, B, u, C, Q, R)
    xp = A @ x + B @ u
    Pp = A @ P @ A.T + Q
    S = C @ Pp @ C.T + R
    K = Pp @ C.T @ np.linalg.inv(S)
    e = z - C @ xp
    IKC = np.eye(3) - K @ C
    np.testing.assert_allclose(xn, xp + K @ e, rtol=1e-12)
    np.testing.assert_allclose(Pn, IKC @ Pp @ IKC.T + K @ R @ K.T, rtol=1e-11)
    np.testing.assert_allclose(
        out["loglik"][0, 0],
        -0.5 * (e @ np.linalg.solve(S, e) + np.log(np.linalg.det(2 * np.pi * S))),
        rtol=1e-12,
    )
    np.testing.assert_allclose(epn, z - C @ (xp + K @ e), rtol=1e-11, atol=1e-14)
    np.testing.assert_array_equal(eppn, ep)
    np.testing.assert_allclose(out["S"][0, 0], S, rtol=1e-12)


@pytest.mark.parametrize("mapping", ["full", "cov"])
def test_svsf_cov_sample_is_smm_eq_2_5_to_2_10(mapping: str) -> None:
    from chatterspec.filters.svsf_cov import SVSFCov
    from chatterspec.plants.models import LinearModel

    A, B, C, Q, R, P, x, u, z, ep, epp = _system(3 if mapping == "full" else 2)
    xp = A @ x + B @ u
    e = z - C @ xp
    psi = np.abs(e) * np.linspace(0.5, 2.0, len(e))  # some channels saturated, some not
    f = SVSFCov(LinearModel(A, B, C, Q, R, 0.01), psi=psi, gamma=0.4, mapping=mapping)
    xn, Pn, _, _, _ = _one_sample(f._correction_step(), x, P, ep, epp, z, A, B, u, C, Q, R)
    Pp = A @ P @ A.T + Q
    M = np.linalg.inv(C) if mapping == "full" else Pp @ C.T @ np.linalg.inv(C @ Pp @ C.T)
    kappa = (np.abs(e) + 0.4 * np.abs(ep)) * sat(e / psi) / e  # eq (2.5), diag(e)^-1 explicit
    K = M @ np.diag(kappa)
    IKC = np.eye(3) - K @ C
    np.testing.assert_allclose(xn, xp + K @ e, rtol=1e-11)  # eq (2.8)
    np.testing.assert_allclose(Pn, IKC @ Pp @ IKC.T + K @ R @ K.T, rtol=1e-10)  # eq (2.9)


def test_second_order_svsf_sample_is_detc_eq_9_and_10() -> None:
    from chatterspec.filters.svsf2 import SecondOrderSVSF
    from chatterspec.plants.models import LinearModel

    A, B, C, Q, R, P, x, u, z, ep, epp = _system(3)
    f = SecondOrderSVSF(LinearModel(A, B, C, Q, R, 0.01), gamma=0.3, lam=0.6)
    xn, Pn, epn, eppn, _ = _one_sample(f._correction_step(), x, P, ep, epp, z, A, B, u, C, Q, R)
    xp = A @ x + B @ u
    e = z - C @ xp
    dz = e - (0.3 + 0.6) * ep + 0.3 * 0.6 * epp  # eq (9)
    np.testing.assert_allclose(xn, xp + np.linalg.solve(C, dz), rtol=1e-11)  # eq (10), M = H^-1
    np.testing.assert_allclose(epn, (0.3 + 0.6) * ep - 0.3 * 0.6 * epp, rtol=1e-9, atol=1e-13)  # eq (21)
    np.testing.assert_array_equal(eppn, ep)
    Pp = A @ P @ A.T + Q
    K = np.linalg.inv(C) @ np.diag(np.clip(dz / e, 0.0, 2.0))  # [IMM] eq (12), clipped
    IKC = np.eye(3) - K @ C
    np.testing.assert_allclose(Pn, IKC @ Pp @ IKC.T + K @ R @ K.T, rtol=1e-10)


def test_bank_steps_combine_probabilities_and_likelihood() -> None:
    rng = np.random.default_rng(7)
    r, n, m = 3, 4, 2
    mu = np.array([0.2, 0.5, 0.3])
    xs = rng.standard_normal((r, n)) * [1.0, 10.0, 0.1, 3.0]  # modes that really differ
    G = rng.standard_normal((r, n, n))
    Ps = G @ np.swapaxes(G, -1, -2) + np.eye(n)
    x, P = np.empty(n), np.empty((n, n))
    bank.combine_step(mu, xs, Ps, x, P, r, n)
    x_ref = mu @ xs
    P_ref = sum(mu[j] * (Ps[j] + np.outer(xs[j] - x_ref, xs[j] - x_ref)) for j in range(r))  # with the spread
    np.testing.assert_allclose(x, x_ref, rtol=1e-13)
    np.testing.assert_allclose(P, P_ref, rtol=1e-12)
    x2, P2 = combine(mu, xs, Ps)
    np.testing.assert_allclose(x, x2, rtol=1e-13)
    np.testing.assert_allclose(P, P2, rtol=1e-12)
    # probabilities: softmax of the log weights, then the floor and renormalization
    lw = np.array([0.0, -800.0, -1.0])
    out = np.empty(r)
    assert bank.mode_probabilities_step(lw.copy(), out, 1e-3, r)
    raw = np.exp(lw - lw.max()) / np.exp(lw - lw.max()).sum()
    floored = np.maximum(raw, 1e-3)
    np.testing.assert_allclose(out, floored / floored.sum(), rtol=1e-14)
    assert out[1] > 1e-3 / 2  # the floored weight survives (it would be 0 without the floor)
    np.testing.assert_allclose(out, normalize_log_weights(lw, 1e-3), rtol=1e-14)
    assert not bank.mode_probabilities_step(np.full(r, -np.inf), out, 0.0, r)
    # likelihood: the Gaussian log density
    S = np.array([[2.0, 0.3], [0.3, 0.5]])
    e = np.array([0.4, -0.7])
    got = bank.log_gaussian_step(
        e, S, m, np.empty((m, m)), np.empty((m, m)), np.empty(m), np.empty(m), np.empty(2 * m)
    )
    ref = -0.5 * (e @ np.linalg.solve(S, e) + np.log(np.linalg.det(2 * np.pi * S)))
    assert got == pytest.approx(ref, rel=1e-12)
    assert float(log_gaussian(e, S)) == pytest.approx(ref, rel=1e-12)
