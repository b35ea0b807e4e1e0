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
from typing import Any, cast

import numpy as np

from .. import _jit
from ..detection.alarms.steps import FRAME
from ..detection.spectral import power_step
from ..detection.verdicts import peak_channel, score_step
from ..filters.svsf_recursion import closed_form_step, matvec_step, rows_times_step, svsf_step

__all__: list[str] = []


def _private_r2c() -> Callable[..., Any] | None:
    """pocketfft's ``r2c`` as ``scipy.fft.rfft`` calls it, or None when this SciPy does not have it.

    The name is private to SciPy: it is taken only if it imports, accepts the call :func:`frame_rfft`
    makes and gives the bits of the public ``scipy.fft.rfft`` on a probe frame (checked once, at
    import); any other SciPy takes the public function.
    """
    try:
        import scipy.fft
        from scipy.fft._pocketfft.pypocketfft import r2c

        probe = np.cos(np.arange(2 * 250, dtype=float) * 0.37).reshape(2, 250)
        same = np.array_equal(r2c(probe, (-1,), True, 0, None, 1), scipy.fft.rfft(probe, axis=-1))
    except Exception:  # pragma: no cover - depends on the SciPy version
        return None
    return r2c if same else None


_r2c = _private_r2c()


def frame_rfft(x: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    """``scipy.fft.rfft(x, axis=-1)`` of the tapered frames ``x`` (float, any strides), without its per-call
    Python work; written to ``out`` (complex, ``x.shape[:-1] + (bins,)``) when given.

    ``scipy.fft.rfft`` dispatches through its backend layer, converts and checks its argument and then
    calls pocketfft's ``r2c`` on the last axis, unnormalized, one worker: 5-10 us of Python per
    call, a tenth of a 1000-sample push. The monitor's tapered frames are already a float array of the
    right length, so the same ``r2c`` call gives the same transform (the same bits:
    tests/test_monitor.py); a SciPy where that private call is missing, refuses the arguments or
    gives other bits (checked once at import) takes the public function. ``out``: the monitor's
    buffer, reused push after push (a new 120 kB array per push costs it ~1 us).
    """
    if _r2c is None:  # pragma: no cover - depends on the SciPy version
        import scipy.fft

        y = scipy.fft.rfft(x, axis=-1)
        if out is None:
            return cast(np.ndarray, y)
        out[...] = y
        return out
    return cast(np.ndarray, _r2c(x, (-1,), True, 0, out, 1))


def direct(kernel: Callable[..., Any]) -> Callable[..., Any]:
    """The numba dispatcher behind a lazily compiled kernel (loaded or compiled now), else ``kernel``.

    Calling it skips the lazy wrapper's Python call: the monitor's push calls two kernels per block
    of frames.
    """
    get = getattr(kernel, "dispatcher", None)
    return cast(Callable[..., Any], get()) if get is not None else kernel


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
    ``G u(k)`` by :func:`~chatterspec.filters.svsf_recursion.rows_times_step` (the sums of
    ``_rows_times``; written to ``Gu`` (1, K, n) unless it is empty), the chattering (eq 23) by
    :func:`~chatterspec.filters.svsf_recursion.closed_form_step` into ``e_out`` (1, K, m) from
    ``aux_y`` = y(k|k) = z(k) before the push, and, when ``run_sat``, the sat SVSF by
    :func:`~chatterspec.filters.svsf_recursion.svsf_step` (``y``, ``ep`` (1, n), (1, m) in place;
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
    input. The chattering ``e(k+1|k)`` goes to ``ebuf[:, row]`` (the channel-major frame buffer)
    and ``st``. Returns 0, or 3 (NaN/inf in ``z`` or ``u``: nothing changed).
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
        ebuf[i, row] = closed_form_step(i, z[i], gu[i], aux_PhiT, zp, m)
        st[o_e + i] = ebuf[i, row]
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

#: Layout of the integer constants ``ci`` of :func:`_hop_loop` (:func:`hop_constants`): its header's
#: slots (sizes), then the arrays in this order.
I_M, I_LO, I_NV, I_NT, I_NCV, I_NLOW, I_NP, I_LEGACY, I_W, I_H, I_HEAD = range(11)
#: The float constants ``cf``: ``scale``, ``log n``, the rule's ``h``, then the arrays.
F_SCALE, F_LOGN, F_H, F_HEAD = range(4)


def hop_constants(
    scale: float,
    lo: int,
    thr: np.ndarray,
    positions: np.ndarray,
    freqs: np.ndarray,
    score_args: tuple[Any, ...],
    h: float,
    p: np.ndarray,
    legacy: bool,
    n_window: int,
    n_hop: int,
) -> tuple[np.ndarray, np.ndarray]:
    """The constants of :func:`_hop_loop` packed once into two arrays ``(cf, ci)`` (floats, integers).

    ``thr`` (nv, m), ``positions`` (nv,), ``freqs`` (nv,): the verdict's tested bins from ``lo``,
    their thresholds and frequencies (Hz); ``score_args``: the frame score's kernel arguments
    (:attr:`FrameScore._kernel_args`); ``h``, ``p``: the alarm rule's threshold and parameters;
    ``legacy``: the rule is fed the per-frame verdict (1.0 / 0.0) instead of the score. A numba call
    unboxes every array argument, so two packed arrays instead of eighteen save their dispatch.
    """
    idx, inv1, invr, off, cnt, cvals, wvals, low, n_low, is_low, hi_invr, inv1T, log_n = score_args
    nv, m = thr.shape
    head = np.zeros(I_HEAD, dtype=np.int64)
    head[[I_M, I_LO, I_NV, I_NT, I_NCV, I_NLOW, I_NP, I_LEGACY, I_W, I_H]] = (
        m, lo, nv, idx.shape[0], cvals.shape[0], low.shape[1], p.shape[0], int(legacy),
        n_window, n_hop,
    )  # fmt: skip
    ints = (head, positions, idx, off, cnt, low, n_low, is_low)
    ci = np.concatenate([np.ravel(a).astype(np.int64) for a in ints])
    fhead = np.zeros(F_HEAD)
    fhead[[F_SCALE, F_LOGN, F_H]] = scale, float(log_n), h
    floats = (fhead, thr, freqs, inv1, invr, cvals, wvals, hi_invr, inv1T, p)
    cf = np.concatenate([np.ravel(np.asarray(a, dtype=float)) for a in floats])
    return np.ascontiguousarray(cf), np.ascontiguousarray(ci)


@_jit.step
def cut(a: np.ndarray, o: int, n: int) -> tuple[np.ndarray, int]:
    """``a[o : o + n]`` and the offset after it: one array of :func:`hop_constants`'s packing."""
    return a[o : o + n], o + n


@_jit.step
def cut_rows(a: np.ndarray, o: int, rows: int, cols: int) -> tuple[np.ndarray, int]:
    """:func:`cut` of ``rows cols`` values, as a (rows, cols) array."""
    return a[o : o + rows * cols].reshape((rows, cols)), o + rows * cols


def _hop_loop(  # type: ignore[no-untyped-def]
    Y, a, j_first, t_first, dt, cf, ci, act, g, count, ring, pos, power, outf, outb, times, peak
):  # pragma: no cover - compiled (compared with the separate calls in tests/test_monitor.py)
    """A block of the monitor's frames in one call: power, verdicts, scores and the alarm rule.

    ``Y`` (1, m, Fb, bins) is the ``rfft`` of the tapered frames ``a .. a + Fb - 1`` of the push
    (global frames from ``j_first``); ``cf``, ``ci``: the constants (:func:`hop_constants`);
    ``act``, ``g``, ``count``, ``ring``, ``pos``: the :class:`AlarmStream`'s state (step ``pos[0]``).
    The loops' steps, in their order within each frame and channel: the power
    (:func:`~chatterspec.detection.spectral.power_step`) into ``power`` (F, bins, m); the
    largest ``S / threshold`` over the tested bins ``lo .. lo + nv - 1``
    (:data:`~chatterspec.detection.verdicts.peak_channel`) into ``outf[0]`` (its bin's frequency into
    ``outf[4]``, ``> 1`` into ``outb[3]``); the frame score
    (:func:`~chatterspec.detection.verdicts.score_step`) into ``outf[1]``; then, per channel over
    the frames, the alarm rule's channel step ``RULE_CHANNEL``
    (:attr:`~chatterspec.detection.alarms.steps.RuleSteps.channel`) fed with ``outf[3]`` = the score,
    or (``legacy``: the per-frame verdict's events) 1.0 where the peak ratio is > 1 and 0.0
    elsewhere: the rule's statistic into ``outf[2]``, its state, starts and ends into ``outb[0:3]``.
    ``times`` (F,) gets the frames' centre times (s) from chattering sample 0 at ``t_first``. The same
    steps as the four separate calls (:class:`~chatterspec.detection.spectral.FrameEngine`,
    ``FrameVerdicts``, ``FrameScore``, ``AlarmStream``), hence their bits.

    Returns 2 when the block has an alarm start or end (events to build), else 1 when an alarm is
    active, else 0. ``peak`` (2, m): per channel, the active fault's largest peak ratio and its
    frequency (Hz), the monitor's event state; for a block that returns 1 (each channel's alarm is
    then constant over the block), each active channel's largest ratio of the block replaces the
    kept one when larger, the first largest as Python's ``max`` picks it (what
    :meth:`~chatterspec.online.monitor.FrameAnalysis._events` does with such a block). A ``peak`` of
    no columns (2, 0) is left to the caller.
    """
    b = _jit.borrow
    Y, cf, ci, act, g, count, ring, pos = b(Y), b(cf), b(ci), b(act), b(g), b(count), b(ring), b(pos)
    power, outf, outb, times, peak = b(power), b(outf), b(outb), b(times), b(peak)
    m, Fb, B = Y.shape[1], Y.shape[2], Y.shape[3]
    lo, nv, nt, ncv = ci[I_LO], ci[I_NV], ci[I_NT], ci[I_NCV]
    nlow, npar, legacy, W, H = ci[I_NLOW], ci[I_NP], ci[I_LEGACY] != 0, ci[I_W], ci[I_H]
    positions, o = cut(ci, I_HEAD, nv)
    idx, o = cut(ci, o, nt)
    off, o = cut_rows(ci, o, nt, m)
    cnt, o = cut_rows(ci, o, nt, m)
    low, o = cut_rows(ci, o, m, nlow)
    n_low, o = cut(ci, o, m)
    is_low, o = cut_rows(ci, o, nt, m)
    scale, log_n, h = cf[F_SCALE], cf[F_LOGN], cf[F_H]
    thr, o = cut_rows(cf, F_HEAD, nv, m)
    freqs, o = cut(cf, o, nv)
    inv1, o = cut_rows(cf, o, nt, m)
    invr, o = cut_rows(cf, o, nt, m)
    cvals, o = cut(cf, o, ncv)
    wvals, o = cut(cf, o, ncv)
    hi_invr, o = cut(cf, o, m)
    inv1T, o = cut_rows(cf, o, m, nt)
    p, o = cut(cf, o, npar)
    pw = power[a : a + Fb]
    peak_ratio = outf[0, a : a + Fb]
    score = outf[1, a : a + Fb]
    stat = outf[2:3, a : a + Fb]
    s3 = outf[3:4, a : a + Fb]
    active, starts, ends = outb[0:1, a : a + Fb], outb[1:2, a : a + Fb], outb[2:3, a : a + Fb]
    k_ratio = np.empty((Fb, m), dtype=np.int64)
    row = np.empty(B)
    for c in range(m):
        for f in range(Fb):
            power_step(Y[0, c, f], scale, row, pw[f], c, B)
    psel = pw[:, lo : lo + nv, :]
    for f in range(Fb):
        for c in range(m):
            peak_channel(psel, thr, thr, positions, k_ratio, peak_ratio, k_ratio, peak_ratio, f, c)
            e = score_step(
                pw, f, c, idx, inv1, invr, off, cnt, cvals, wvals, low, n_low, is_low, hi_invr, inv1T
            )
            score[f, c] = max(e - log_n, 0.0)
            if legacy:
                s3[0, f, c] = 1.0 if peak_ratio[f, c] > 1.0 else 0.0
            else:
                s3[0, f, c] = score[f, c]
            outf[4, a + f, c] = freqs[k_ratio[f, c]]
            outb[3, a + f, c] = peak_ratio[f, c] > 1.0
    for c in range(m):
        RULE_CHANNEL(s3, h, p, act, g, count, ring, pos[0], active, stat, starts, ends, 0, c)
    half = (W - 1) / 2.0
    for f in range(Fb):
        times[a + f] = t_first + ((j_first + a + f) * H + half) * dt
    code = 0
    for f in range(Fb):
        for c in range(m):
            if starts[0, f, c] or ends[0, f, c]:
                return 2
            if active[0, f, c]:
                code = 1
    if code and peak.shape[1] > 0:
        for c in range(m):
            if active[0, 0, c]:
                best, k = peak_ratio[0, c], 0
                for f in range(1, Fb):
                    if peak_ratio[f, c] > best:
                        best, k = peak_ratio[f, c], f
                if best > peak[0, c]:
                    peak[0, c] = best
                    peak[1, c] = outf[4, a + k, c]
    return code


_HOP: dict[int, Callable[..., int]] = {}


def hop_kernel(channel: Callable[..., None]) -> Callable[..., int]:
    """The monitor's block-of-frames loop (:func:`_hop_loop`) with the alarm rule's channel step ``channel``.

    One kernel per channel step (a rule's :attr:`~chatterspec.detection.alarms.steps.RuleSteps.channel`),
    kept for the process; numba inlines the step, so there is no call through a function value.
    """
    kernel = _HOP.get(id(channel))
    if kernel is None:
        kernel = _jit.specialize(_hop_loop, f"hop_{channel.__name__.strip('_')}", RULE_CHANNEL=channel)
        _HOP[id(channel)] = kernel
    return kernel


@_jit.njit
def frames_in(
    buf: np.ndarray,
    nb: int,
    e: np.ndarray,
    check: bool,
    win: np.ndarray,
    hop: int,
    lo: int,
    hi: int,
    n_frames: int,
    tapered: np.ndarray,
) -> int:  # pragma: no cover - compiled (Python form tested in tests/test_monitor.py)
    """The frame buffer's side of a push: append ``e``, taper frames ``lo .. hi - 1``, keep the rest.

    ``buf`` (m, columns), channel-major, holds ``nb`` chattering samples from the next frame's start
    on; ``e`` (K, m) (``nb + K <= columns``) is appended and, when ``check``, checked for NaN/inf
    (then -1 is returned and nothing is consumed: the columns from ``nb`` on are not the buffer's
    yet). Frames ``lo .. hi - 1`` of the ``nb + K`` samples (frame ``f`` starts at sample ``f hop``)
    are tapered into ``tapered[0, :, :hi - lo]`` (1, m, >= hi - lo, W): ``x_c[f hop + k] * win[k]``,
    the product of :class:`~chatterspec.detection.spectral.FrameEngine`'s taper (the same bits).
    When ``hi == n_frames`` (the push's last block) the samples from frame ``n_frames`` 's start on
    move to the buffer's front. Returns the samples the buffer then holds.
    """
    K, m = e.shape
    W = win.shape[0]
    bad = False
    # (each loop indexes a slice from 0: an index numba cannot prove non-negative, such as nb + k, is
    # checked for wraparound on every access, which keeps LLVM from vectorizing the loop: 4x slower)
    for c in range(m):
        x = buf[c, nb : nb + K]
        for k in range(K):
            v = e[k, c]
            x[k] = v
            bad |= (v - v) != 0.0  # NaN for NaN and +-inf, 0 for every finite value
    if check and bad:
        return -1
    n = nb + K
    for c in range(m):
        for f in range(hi - lo):
            s = (lo + f) * hop
            x = buf[c, s : s + W]
            out = tapered[0, c, f]
            for k in range(W):
                out[k] = x[k] * win[k]
    if hi < n_frames:
        return n
    first = n_frames * hop
    if first == 0:
        return n
    for c in range(m):
        x = buf[c]
        src = buf[c, first:n]
        for k in range(n - first):
            x[k] = src[k]
    return n - first


@_jit.njit
def sample_times(t0: float, first: int, count: int, dt: float) -> np.ndarray:  # pragma: no cover - compiled
    """Times (s) ``t0 + j dt`` of samples ``j = first .. first + count - 1`` (a new array).

    Per sample the two correctly rounded operations of the numpy form
    ``t0 + arange(first, first + count, dtype=float) * dt`` (the float ``arange`` of integers is exact
    below 2^53; numba contracts no product and sum into a fused multiply-add), so the same bits
    (tests/test_monitor.py); one call instead of numpy's three passes (:func:`sample_times_numpy`).
    """
    t = np.empty(count)
    for k in range(count):
        t[k] = t0 + float(first + k) * dt
    return t


def sample_times_numpy(t0: float, first: int, count: int, dt: float) -> np.ndarray:
    """:func:`sample_times` in numpy: ``t0 + arange(first, first + count, dtype=float) * dt``, scaled and
    shifted in place (the same bits, without the two temporary arrays)."""
    t = np.arange(first, first + count, dtype=float)
    t *= dt
    t += t0
    return t
