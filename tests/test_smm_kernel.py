"""The compiled SMM-SVSF loop (chatterspec.filters.smm_svsf) against its numpy path.

Both evaluate [SMM] Table 1 (eq 3.1-3.5 with eq 2.1-2.10); numpy sums the products with BLAS and
``einsum`` and takes the likelihood from LAPACK's ``eigh``, the loop sums in loop order and takes
it from a Cholesky factor. Measured on these inputs (eha4-leak-timeline, 2 runs x 1500 samples):
x_post differs by at most 1e-12 of each state's range, mu by 1e-15, loglik by 3e-14 relative, P by
1e-14 relative; the tolerances below are about 100x that. Chunking must give the same bits.
"""

from __future__ import annotations

import numpy as np
import pytest

import chatterspec as cs
from chatterspec import _jit
from chatterspec.filters import smm_svsf
from chatterspec.filters.smm_svsf import SMMSVSF

needs_numba = pytest.mark.skipif(not _jit.enabled(), reason="numba not installed or CHATTERSPEC_JIT=0")


def timeline(T: int, runs: int):  # type: ignore[no-untyped-def]
    sc = cs.scenario("eha4-leak-timeline")
    fs = sc.filter_settings
    sim = cs.simulate(sc, runs=runs, seed=4)
    return fs, sim.z[:, 1 : T + 1], sim.u[:T]


def smm(fs) -> SMMSVSF:  # type: ignore[no-untyped-def]
    return SMMSVSF(fs.mode_models, psi=np.array(fs.psi), gamma=fs.gamma, mapping=fs.mapping)


def numpy_path(f: SMMSVSF) -> SMMSVSF:
    g = smm_like(f)
    object.__setattr__(g, "_compiled", None)
    return g


def smm_like(f: SMMSVSF) -> SMMSVSF:
    return SMMSVSF(f.models, psi=f.psi, gamma=f.gamma, mapping=f.mapping, weight_floor=f.weight_floor)


@needs_numba
def test_compiled_smm_matches_the_numpy_path() -> None:
    fs, z, u = timeline(1500, 2)
    f = smm(fs)
    assert f._compiled is not None
    kw = dict(x0=fs.x0, P0=fs.P0, store={"P_post", "mode_x_post"})
    a, b = f.run(z, u, **kw), numpy_path(f).run(z, u, **kw)
    scale = np.max(np.abs(b.x_post), axis=(0, 1))
    assert np.all(np.max(np.abs(a.x_post - b.x_post), axis=(0, 1)) <= 1e-10 * scale)
    np.testing.assert_allclose(a.mu, b.mu, rtol=0, atol=1e-12)
    np.testing.assert_allclose(a.loglik, b.loglik, rtol=1e-11)
    np.testing.assert_allclose(a.P_post, b.P_post, rtol=1e-11, atol=0)
    np.testing.assert_allclose(a.mode_x_post, b.mode_x_post, rtol=0, atol=1e-10 * scale.max())


@needs_numba
def test_compiled_smm_is_chunk_invariant_bit_for_bit() -> None:
    fs, z, u = timeline(300, 3)
    f = smm(fs)
    whole = f.run(z, u, x0=fs.x0, P0=fs.P0, store={"P_post"})
    state = f.initialize(fs.x0, fs.P0, runs=3)
    parts = []
    for a, b in ((0, 1), (1, 120), (120, 121), (121, 300)):
        state, out = f.update(state, z[:, a:b], u[a:b], store={"P_post"})
        parts.append(out)
    for name in ("x_post", "mu", "loglik", "P_post"):
        np.testing.assert_array_equal(
            np.concatenate([getattr(o, name) for o in parts], axis=1), getattr(whole, name)
        )
    one = f.run(z[2:], u, x0=fs.x0, P0=fs.P0)  # one run alone: the bits it has among three
    np.testing.assert_array_equal(one.x_post[0], whole.x_post[2])


@needs_numba
def test_loop_python_form_matches() -> None:
    fs, z, u = timeline(5, 2)
    f = smm(fs)
    state = f.initialize(fs.x0, fs.P0, runs=2)
    c = lambda a: np.array(a, dtype=float, order="C")  # noqa: E731
    args = (c(state.x), c(state.P), c(state.mu), c(state.e_post), np.zeros((2, 4)))
    o = smm_svsf.run_smm(f._compiled, f.weight_floor, *args, z, u[None], False, False, python=True)
    ref = numpy_path(f).run(z, u, x0=fs.x0, P0=fs.P0)
    np.testing.assert_allclose(o["mu"], ref.mu, rtol=0, atol=1e-12)
    np.testing.assert_allclose(o["x"], ref.x_post, rtol=1e-10)


def test_models_without_compiled_steps_take_the_numpy_path() -> None:
    fs, _, _ = timeline(5, 1)
    lin = [m.linearize(fs.x0, np.zeros(1)) for m in fs.mode_models]
    assert smm_svsf.smm_spec(tuple(lin), smm(fs)._svsf._correction_step()) is not None  # linear: compiled
    from dataclasses import replace

    user = [replace(m, f=lambda x, u, c=m.f: c(x, u)) for m in fs.mode_models]  # a Python f: no steps
    assert SMMSVSF(user, psi=np.array(fs.psi), gamma=fs.gamma, mapping=fs.mapping)._compiled is None
