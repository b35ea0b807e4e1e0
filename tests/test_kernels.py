"""Compiled kernels (chatterspec._jit) against the numpy path they replace.

Both paths evaluate the same per-element arithmetic; the only difference is the
order of the terms in the small matrix-vector products (BLAS in the numpy loop,
j = 0..n-1 in the kernel), i.e. a few ulps per step. The SVSF recursion is
stable (|1 - sat'| <= 1 and Phi is stable), so these differences do not grow:
1e-12 of each channel's scale (~1e4 ulps) bounds them with a wide margin, the
same tolerance as the closed-form/recursion test of tests/test_svsf.py.
"""

from __future__ import annotations

import numpy as np
import pytest

from chatterspec import _jit
from chatterspec.filters import svsf as svsf_mod
from chatterspec.filters.svsf import SVSF, auxiliary_svsf
from chatterspec.plants.scenarios import scenario
from chatterspec.plants.simulate import simulate

needs_numba = pytest.mark.skipif(not _jit.HAVE_NUMBA, reason="numba not installed (pip install '.[fast]')")

REL_TOL = 1e-12  # see the module docstring


def _filters() -> dict[str, tuple[str, SVSF, np.ndarray | None]]:
    eha = scenario("eha-healthy").nominal
    so = scenario("so-boundary-layer").nominal
    return {
        "sat-full": ("eha-healthy", SVSF(eha, psi=3 * np.sqrt(np.diag(eha.R))), None),
        "sat-reduced": ("so-boundary-layer", SVSF(so, psi=8e-4, psi_lower=0.8), None),
        "sgn-reduced": ("so-boundary-layer", SVSF(so, switching="sgn"), None),
        # non-zero initial error: the sgn filter leaves the closed form and runs the recursion
        "sgn-full-x0": ("eha-healthy", auxiliary_svsf(eha, gamma=0.5), np.array([0.01, -0.02, 0.5])),
    }


def _run(f: SVSF, z: np.ndarray, u: np.ndarray, x0: np.ndarray | None):
    return f.run(z, u, x0=x0, store_states=True, store_post_error=True, store_lower=True)


@needs_numba
@pytest.mark.parametrize("case", list(_filters()))
def test_compiled_svsf_equals_numpy_path(case: str, monkeypatch: pytest.MonkeyPatch) -> None:
    name, f, x0 = _filters()[case]
    sim = simulate(scenario(name), runs=3, seed=11)
    z, u = sim.z[:, :1500], sim.u[:1500]
    monkeypatch.setenv("CHATTERSPEC_JIT", "1")
    fast = _run(f, z, u, x0)
    monkeypatch.setenv("CHATTERSPEC_JIT", "0")
    ref = _run(f, z, u, x0)
    # The output errors are differences of measurement-sized numbers (e = z - z_pred, e(k|k) =
    # z - y_u), so their rounding is counted in ulps of z, not of the (much smaller) errors;
    # e_lower = Phi22 Phi12^-1 e scales that by the row sums of |Phi22 Phi12^-1|.
    z_scale = np.abs(z).max()
    scales = {
        "e_prior": z_scale,
        "e_post": z_scale,
        "x_post": np.abs(ref.x_post).max(axis=(0, 1)),
        "e_lower": None if f._L is None else z_scale * np.abs(f._L).sum(axis=1),
    }
    for attr, scale in scales.items():
        a, b = getattr(fast, attr), getattr(ref, attr)
        if b is None:
            assert a is None, attr
            continue
        err = np.abs(a - b).max(axis=(0, 1))
        assert np.all(err <= REL_TOL * scale), (attr, err / scale)


@needs_numba
def test_compiled_kernel_equals_its_python_form_bitwise() -> None:
    """numba compiles the kernel without fastmath: same operations, same order, same bits."""
    sc = scenario("so-boundary-layer")
    sim = simulate(sc, runs=2, seed=4)
    f = SVSF(sc.nominal, psi=8e-4, psi_lower=0.8)
    z = np.ascontiguousarray(sim.z[:, 1:60])
    Gu = np.ascontiguousarray(svsf_mod._rows_times(sim.u[:59], f._GT)[None])
    state = f.initialize(sim.z[:, 0], x0=np.array([0.001, -0.01]))
    K, n, m = z.shape[1], 2, 1

    def call(kernel):
        y, ep = state.y.copy(), state.e_post.copy()
        outs = [np.empty((2, K, m)), np.empty((2, K, n)), np.empty((2, K, m)), np.empty((2, K, n - m))]
        kernel(z, Gu, f._PhiT, f._L, f._P, f._inv_psi, f.gamma, f._S_inv, y, ep, *outs)
        return [y, ep, *outs]

    for a, b in zip(call(svsf_mod._svsf_kernel), call(svsf_mod._svsf_kernel.py_func), strict=True):
        np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("jit", ["0", "1"])
def test_online_single_samples_equal_batch_on_both_paths(jit: str, monkeypatch: pytest.MonkeyPatch) -> None:
    """The monitor's use: 1-sample updates give the batch bits, whichever path is active."""
    if jit == "1" and not _jit.HAVE_NUMBA:
        pytest.skip("numba not installed")
    monkeypatch.setenv("CHATTERSPEC_JIT", jit)
    sc = scenario("eha-healthy")
    sim = simulate(sc, runs=1, seed=2)
    z, u = sim.z[0, :400], sim.u[:400]
    f = SVSF(sc.nominal, psi=3 * np.sqrt(np.diag(sc.nominal.R)))
    batch = f.run(z, u, store_states=True)
    state = f.initialize(z[0])
    e, x = [], []
    for k in range(1, len(z)):
        state, out = f.update(state, z[k : k + 1], u[k - 1 : k], store_states=True, check=False)
        e.append(out.e_prior[0, 0])
        x.append(out.x_post[0, 0])
    np.testing.assert_array_equal(np.array(e), batch.e_prior[1:])
    np.testing.assert_array_equal(np.array(x), batch.x_post[1:])


def test_enabled_follows_the_environment(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("CHATTERSPEC_JIT", "0")
    assert not _jit.enabled()
    monkeypatch.setenv("CHATTERSPEC_JIT", "1")
    assert _jit.enabled() == _jit.HAVE_NUMBA
