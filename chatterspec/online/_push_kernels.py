"""Per-push helpers of the online monitor: frame verdicts and compiled loops (see :mod:`chatterspec._jit`).

Each kernel does, in one pass, what a few numpy calls (or Python-level calls of
the SVSF) do in :mod:`chatterspec.online.monitor`, with the same correctly
rounded operations in the same order, so that the monitor's numbers do not
depend on whether numba is installed (tests/test_monitor.py compares the paths
bit for bit; the sat SVSF's numpy fallback is the one exception, equal to
1e-12, see :meth:`chatterspec.filters.svsf.SVSF.update`).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import cast

import numpy as np

from .. import _jit
from ..detection.alarms.steps import FRAME
from ..detection.spectral import power_step
from ..detection.verdicts import peak_channel, score_step
from ..filters.svsf_steps import closed_form_step, matvec_step, rows_times_step, svsf_step

__all__: list[str] = []

#: Sizes of :func:`_filters_loop` (states, outputs, unmeasured states), bound by :func:`filters_kernel`;
#: 0 reads them from the arrays.
NX = NZ = NL = 0


def _filters_loop(
    z: np.ndarray,
    u: np.ndarray,
    GT: np.ndarray,
    aux_PhiT: np.ndarray,
    aux_y: np.ndarray,
    e_out: np.ndarray,
    Gu: np.ndarray,
    run_sat: bool,
    PhiT: np.ndarray,
    L: np.ndarray,
    P: np.ndarray,
    inv_psi: np.ndarray,
    gamma: float,
    S_inv: np.ndarray,
    y: np.ndarray,
    ep: np.ndarray,
    sat_e: np.ndarray,
    x_out: np.ndarray,
    none: np.ndarray,
) -> None:  # pragma: no cover - compiled (Python form tested in tests/test_monitor.py)
    """One push of the monitor's two filters in one call: G u(k), the aux chattering, the sat SVSF.

    ``z`` (1, K, m) = z(k+1); ``u`` (K, p), p >= 1, = u(k); ``GT`` = G^T (p, n). Per sample:
    ``G u(k)`` by :func:`~chatterspec.filters.svsf_steps.rows_times_step` (the sums of
    ``_rows_times``; written to ``Gu`` (1, K, n) unless it is empty), the chattering (eq 23) by
    :func:`~chatterspec.filters.svsf_steps.closed_form_step` into ``e_out`` (1, K, m) from
    ``aux_y`` = y(k|k) = z(k) before the push, and, when ``run_sat``, the sat SVSF by
    :func:`~chatterspec.filters.svsf_steps.svsf_step` (``y``, ``ep`` (1, n), (1, m) in place;
    ``sat_e`` (1, K, m) unless empty, ``x_out`` (1, K, n) = S^-1 y). ``none`` is unused (kept for
    the call signature). The steps of ``SVSF.update``, so the same bits (tests/test_monitor.py).
    A template: :func:`filters_kernel` binds ``NX``, ``NZ`` (0: sizes read from the arrays).
    """
    b = _jit.borrow
    z, u, GT, aux_PhiT, aux_y, e_out, Gu = b(z), b(u), b(GT), b(aux_PhiT), b(aux_y), b(e_out), b(Gu)
    PhiT, L, P, inv_psi, S_inv, y, ep = b(PhiT), b(L), b(P), b(inv_psi), b(S_inv), b(y), b(ep)
    sat_e, x_out = b(sat_e), b(x_out)
    K = z.shape[1]
    p = GT.shape[0]
    n = NX if NX > 0 else GT.shape[1]
    m = NZ if NZ > 0 else z.shape[2]
    nl = NL if NX > 0 else L.shape[0]
    want_gu = Gu.shape[0] > 0
    want_e = sat_e.shape[0] > 0
    gu = _jit.scratch(n)
    zp = _jit.scratch(m)
    yc = _jit.scratch(n)
    epc = _jit.scratch(m)
    yp = _jit.scratch(n)
    e = _jit.scratch(m)
    le = _jit.scratch(nl)
    xc = _jit.scratch(n)
    for i in range(m):
        zp[i] = aux_y[0, i]
    if run_sat:
        for i in range(n):
            yc[i] = y[0, i]
        for i in range(m):
            epc[i] = ep[0, i]
    for k in range(K):
        rows_times_step(u[k], GT, gu, p, n)
        if want_gu:
            for i in range(n):
                Gu[0, k, i] = gu[i]
        for i in range(m):
            e_out[0, k, i] = closed_form_step(i, z[0, k, i], gu[i], aux_PhiT, zp, m)
        for i in range(m):
            zp[i] = z[0, k, i]
        if run_sat:
            svsf_step(z[0, k], gu, PhiT, L, P, inv_psi, gamma, yc, epc, yp, e, le, n, m, nl, True)
            if want_e:
                for i in range(m):
                    sat_e[0, k, i] = e[i]
            matvec_step(S_inv, yc, xc, n, n)
            for i in range(n):
                x_out[0, k, i] = xc[i]
    if run_sat:
        for i in range(n):
            y[0, i] = yc[i]
        for i in range(m):
            ep[0, i] = epc[i]


#: The push loop for any model size (sizes read from the arrays).
_filters_kernel = _jit.specialize(_filters_loop, "any", NX=0, NZ=0, NL=0)


def filters_kernel(n: int, m: int) -> Callable[..., None]:
    """The push loop for n states and m outputs (full measurement: n = m); small sizes unrolled.

    The same template and steps as :data:`_filters_kernel`, hence the same bits; literal sizes let
    LLVM keep the per-run state in registers (the EHA's 3 states: 0.53 against 1.36 ms per minute
    of 1 kHz data for both filters, the same as the loop written out by hand).
    """
    return _jit.specialize_sizes(_filters_loop, "push", {"NX": n, "NZ": m, "NL": n - m})


@_jit.step
def one_offsets(n: int, m: int, p: int, nl: int) -> tuple[int, int, int, int, int, int, int, int]:
    """Offsets in ``cst`` of :func:`_filters_one` after its 8-value header: ``G^T`` (p, n), the aux
    filter's ``Phi^T`` (m, m), the sat filter's ``Phi^T`` (n, n), ``L``, ``P`` (nl, m), ``1/psi`` (n),
    ``S^-1`` (n, n), and the length."""
    o_GT = 8
    o_aux = o_GT + p * n
    o_PhiT = o_aux + m * m
    o_L = o_PhiT + n * n
    o_P = o_L + nl * m
    o_psi = o_P + nl * m
    o_Si = o_psi + n
    return o_GT, o_aux, o_PhiT, o_L, o_P, o_psi, o_Si, o_Si + n * n


def _filters_one(cst, st, z, u, ebuf, row):  # type: ignore[no-untyped-def]  # pragma: no cover - compiled
    """One sample of the monitor's two filters: :func:`_filters_loop`'s body on packed arrays.

    ``cst``: header ``[n, m, p, nl, run_sat, gamma, 0, 0]``, then :func:`one_offsets`. ``st`` (the
    filters' state between samples and pushes): the pending input ``u(k)`` (p), the aux filter's
    ``y(k|k) = z(k)`` (m), the sat filter's ``y`` (n) and ``e(k|k)`` (m), its last estimate
    ``S^-1 y`` (n), the last chattering (m). ``z`` (m,) = z(k+1); ``u`` (p,) becomes the pending
    input. The chattering ``e(k+1|k)`` goes to ``ebuf[row]`` (the frame buffer) and ``st``. Returns
    0, or 3 (NaN/inf in ``z`` or ``u``: nothing changed).
    """
    b = _jit.borrow
    cst, st, z, u, ebuf = b(cst), b(st), b(z), b(u), b(ebuf)
    n = NX if NX > 0 else int(cst[0])
    m = NZ if NZ > 0 else int(cst[1])
    p = int(cst[2])
    nl = NL if NX > 0 else int(cst[3])
    run_sat, gamma = cst[4] != 0.0, cst[5]
    for i in range(m):
        if not np.isfinite(z[i]):
            return 3
    for i in range(p):
        if not np.isfinite(u[i]):
            return 3
    o_GT, o_aux, o_PhiT, o_L, o_P, o_psi, o_Si, _ = one_offsets(n, m, p, nl)
    GT = cst[o_GT:o_aux].reshape((p, n))
    aux_PhiT = cst[o_aux:o_PhiT].reshape((m, m))
    gu = _jit.scratch(n)
    zp = _jit.scratch(m)
    for i in range(m):
        zp[i] = st[p + i]
    rows_times_step(st[0:p], GT, gu, p, n)
    o_e = p + 2 * m + 2 * n
    for i in range(m):
        ebuf[row, i] = closed_form_step(i, z[i], gu[i], aux_PhiT, zp, m)
        st[o_e + i] = ebuf[row, i]
    if run_sat:
        PhiT = cst[o_PhiT:o_L].reshape((n, n))
        L = cst[o_L:o_P].reshape((nl, m))
        P = cst[o_P:o_psi].reshape((nl, m))
        inv_psi = cst[o_psi:o_Si]
        S_inv = cst[o_Si : o_Si + n * n].reshape((n, n))
        yc = _jit.scratch(n)
        epc = _jit.scratch(m)
        yp = _jit.scratch(n)
        e = _jit.scratch(m)
        le = _jit.scratch(nl)
        xc = _jit.scratch(n)
        o_y = p + m
        for i in range(n):
            yc[i] = st[o_y + i]
        for i in range(m):
            epc[i] = st[o_y + n + i]
        svsf_step(z, gu, PhiT, L, P, inv_psi, gamma, yc, epc, yp, e, le, n, m, nl, True)
        matvec_step(S_inv, yc, xc, n, n)
        for i in range(n):
            st[o_y + i] = yc[i]
            st[o_y + n + m + i] = xc[i]
        for i in range(m):
            st[o_y + n + i] = epc[i]
    for i in range(m):
        st[p + i] = z[i]
    for i in range(p):
        st[i] = u[i]
    return 0


def filters_one_kernel(n: int, m: int) -> Callable[..., int]:
    """:func:`_filters_one` for n states and m outputs (full measurement: n = m; small sizes unrolled)."""
    return _jit.specialize_sizes(_filters_one, "push_one", {"NX": n, "NZ": m, "NL": n - m})


#: The alarm rule's channel step :func:`_hop_loop` inlines (:attr:`RuleSteps.channel`, bound by
#: :func:`hop_kernel`; this default: the frame rule's).
RULE_CHANNEL = cast(Callable[..., None], FRAME.channel)


def _hop_loop(  # type: ignore[no-untyped-def]  # (35 arrays and scalars: see the docstring)
    Y,
    scale,
    power,
    lo,
    thr,
    positions,
    k_ratio,
    peak_ratio,
    idx,
    inv1,
    invr,
    off,
    cnt,
    cvals,
    wvals,
    low,
    n_low,
    is_low,
    hi_invr,
    inv1T,
    log_n,
    score,
    legacy,
    h,
    p,
    act,
    g,
    count,
    ring,
    pos,
    s3,
    active,
    stat,
    starts,
    ends,
):  # pragma: no cover - compiled (Python form tested in tests/test_monitor.py)
    """A block of the monitor's frames in one call: power, verdicts, scores and the alarm rule.

    ``Y`` (1, m, F, bins) is the ``rfft`` of the tapered frames; the loops' steps, in their order
    within each frame and channel: the power (:func:`~chatterspec.detection.spectral.power_step`)
    into ``power`` (F, bins, m); the largest ``S / threshold`` over the tested bins ``lo ..
    lo + len(positions) - 1`` (:data:`~chatterspec.detection.verdicts.peak_channel`) into ``k_ratio``,
    ``peak_ratio`` (F, m); the frame score (:func:`~chatterspec.detection.verdicts.score_step`,
    its arguments) into ``score``; then, per channel over the frames, the alarm rule's channel step
    ``RULE_CHANNEL`` (:attr:`~chatterspec.detection.alarms.steps.RuleSteps.channel`: threshold ``h``,
    parameters ``p``, the :class:`AlarmStream`'s state arrays, step ``pos[0]``) fed with ``s3``
    (1, F, m) = the score, or (``legacy``: the per-frame
    verdict's events) 1.0 where ``peak_ratio > 1`` and 0.0 elsewhere. The same steps as the four
    separate calls (:class:`~chatterspec.detection.spectral.FrameEngine`, ``FrameVerdicts``,
    ``FrameScore``, ``AlarmStream``), hence their bits.
    """
    b = _jit.borrow
    Y, power, thr, positions, k_ratio, peak_ratio, score = (
        b(Y), b(power), b(thr), b(positions), b(k_ratio), b(peak_ratio), b(score),
    )  # fmt: skip
    idx, inv1, invr, off, cnt, cvals, wvals = b(idx), b(inv1), b(invr), b(off), b(cnt), b(cvals), b(wvals)
    low, n_low, is_low, hi_invr, inv1T = b(low), b(n_low), b(is_low), b(hi_invr), b(inv1T)
    p, act, g, count, ring, pos, s3 = b(p), b(act), b(g), b(count), b(ring), b(pos), b(s3)
    active, stat, starts, ends = b(active), b(stat), b(starts), b(ends)
    m, F, B = Y.shape[1], Y.shape[2], Y.shape[3]
    row = np.empty(B)
    for c in range(m):
        for f in range(F):
            power_step(Y[0, c, f], scale, row, power[f], c, B)
    psel = power[:, lo : lo + positions.shape[0], :]
    for f in range(F):
        for c in range(m):
            peak_channel(psel, thr, thr, positions, k_ratio, peak_ratio, k_ratio, peak_ratio, f, c)
            e = score_step(
                power, f, c, idx, inv1, invr, off, cnt, cvals, wvals, low, n_low, is_low, hi_invr, inv1T
            )
            score[f, c] = max(e - log_n, 0.0)
            if legacy:
                s3[0, f, c] = 1.0 if peak_ratio[f, c] > 1.0 else 0.0
            else:
                s3[0, f, c] = score[f, c]
    for c in range(m):
        RULE_CHANNEL(s3, h, p, act, g, count, ring, pos[0], active, stat, starts, ends, 0, c)


_HOP: dict[int, Callable[..., None]] = {}


def hop_kernel(channel: Callable[..., None]) -> Callable[..., None]:
    """The monitor's block-of-frames loop (:func:`_hop_loop`) with the alarm rule's channel step ``channel``.

    One kernel per channel step (a rule's :attr:`~chatterspec.detection.alarms.steps.RuleSteps.channel`),
    kept for the process; numba inlines the step, so there is no call through a function value.
    """
    kernel = _HOP.get(id(channel))
    if kernel is None:
        kernel = _jit.specialize(_hop_loop, f"hop_{channel.__name__.strip('_')}", RULE_CHANNEL=channel)
        _HOP[id(channel)] = kernel
    return kernel
