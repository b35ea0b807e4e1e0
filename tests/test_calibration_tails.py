"""Bounded-memory calibration quantiles (tail histograms) against the exact top-k path."""

from __future__ import annotations

import numpy as np
import pytest

from chatterspec.studies.calibration import healthy as th
from chatterspec.studies.calibration.thresholds import calibrate
from chatterspec.studies.intervals import _pooled_ranks

QUANTITIES = ("per_bin", "per_frame")


def _triples(cal):
    out = {k: (getattr(cal, k), getattr(cal, k + "_low"), getattr(cal, k + "_high")) for k in QUANTITIES}
    fw = cal.frame_family_wise
    out["frame_family_wise"] = tuple(
        np.array([getattr(x, a) for x in fw]) for a in ("value", "ci_low", "ci_high")
    )
    return out


def _assert_within_one_bucket(exact, hist, width):
    """Point: never below the exact order statistic, at most one fine bucket (relative ``width``) above;
    interval: contains the exact interval (widened outward to bucket edges)."""
    (ev, el, eh), (hv, hl, hh) = exact, hist
    assert np.all(hv >= ev * (1 - 1e-12))
    assert np.all(hv <= ev * (1 + width) * (1 + 1e-9))
    assert np.all(hl <= el)
    assert np.all(hh >= eh)


@pytest.fixture(scope="module")
def pair():
    kw = {"alpha": 0.02, "runs": 320, "seed": 3, "progress": False}
    return calibrate("so-healthy-low", **kw), calibrate("so-healthy-low", tail_budget=0, **kw), kw


def test_forced_histogram_agrees_with_exact_within_one_bucket(pair):
    exact, hist, _ = pair
    assert exact.tails["method"] == "exact"
    assert hist.tails["method"] == "histogram"
    assert hist.tails["outside_window"] == 0
    assert hist.tails["pilot_runs"] == 64  # the smallest pilot (one random block) for budget 0
    width = hist.tails["fine_rel_width"]
    assert 0 < width < 0.05  # a 64-run pilot gives a wide window; the default budget a ~1e-3 one
    e, h = _triples(exact), _triples(hist)
    for key in e:
        _assert_within_one_bucket(e[key], h[key], width)
    # the record family-wise quantile stays exact (per-run maxima, 24 bytes per run)
    assert [q.to_dict() for q in exact.family_wise] == [q.to_dict() for q in hist.family_wise]


def test_budget_switch_at_exact_bytes(pair):
    exact, _, kw = pair
    need = exact.tails["exact_bytes"]
    at = calibrate("so-healthy-low", tail_budget=need, **kw)
    below = calibrate("so-healthy-low", tail_budget=need - 1, **kw)
    assert at.tails["method"] == "exact" and below.tails["method"] == "histogram"
    np.testing.assert_array_equal(at.per_frame, exact.per_frame)


def test_histogram_identical_for_any_chunking_and_workers(pair):
    _, hist, kw = pair
    other = calibrate("so-healthy-low", tail_budget=0, chunk_runs=64, workers=2, **kw)
    a, b = _triples(hist), _triples(other)
    for key in a:
        for x, y in zip(a[key], b[key], strict=True):
            np.testing.assert_array_equal(x, y)  # integer counts: bit-identical, not just close


def test_tails_survive_save_and_load(pair, tmp_path):
    from chatterspec.studies.calibration.result import load_calibration

    _, hist, _ = pair
    back = load_calibration(hist.save(tmp_path / "cal.npz"))
    assert back.tails == hist.tails
    np.testing.assert_array_equal(back.per_frame_high, hist.per_frame_high)


def test_nonlinear_path_uses_histograms_too():
    kw = {"runs": 128, "seed": 2, "progress": False}
    exact = calibrate("eha4-healthy", **kw)
    hist = calibrate("eha4-healthy", tail_budget=0, **kw)
    assert (exact.tails["method"], hist.tails["method"]) == ("exact", "histogram")
    e, h = _triples(exact), _triples(hist)
    for key in e:
        _assert_within_one_bucket(e[key], h[key], hist.tails["fine_rel_width"])


# ---------------------------------------------------------------- the histogram itself, on known samples
def _exact(y, n, n_eff, q, conf):
    point, lo, hi = _pooled_ranks(n, n_eff, q, conf)
    s = np.sort(y, axis=0)
    low = s[lo - 1] if lo >= 1 else np.full(s.shape[1:], -np.inf)
    high = s[hi - 1] if hi <= n else np.full(s.shape[1:], np.inf)
    return s[point - 1], low, high


@pytest.mark.parametrize(("q", "n"), [(0.99, 5000), (0.9, 700), (0.999, 3000)])
def test_counts_read_brackets_exact_order_statistics(q, n):
    rng = np.random.default_rng(11)
    y = rng.exponential(size=(n, 40, 2))  # chi-squared(2)/2: the healthy normalized power
    true = -np.log(1 - q)
    lo = np.full((40, 2), true / 1.6)  # wide enough for the sample scatter at n = 700
    hi = np.full((40, 2), true * 1.6)
    lo[0, 0], hi[0, 0] = 0.01, 0.02  # a window the quantile misses: read at the coarse resolution
    counts = th.bucket_counts(y[: n // 3], lo, hi) + th.bucket_counts(y[n // 3 :], lo, hi)
    np.testing.assert_array_equal(counts, th.bucket_counts(y, lo, hi))  # merging = adding counts
    assert counts.sum(axis=-1).min() == n
    v, low, high, outside = th.quantile_from_counts(counts, lo, hi, n, q, 0.99, n)
    ev, el, eh = _exact(y, n, n, q, 0.99)
    assert outside == 1
    width = th.fine_rel_width(lo[1:], hi[1:])
    _assert_within_one_bucket((ev[1:], el[1:], eh[1:]), (v[1:], low[1:], high[1:]), width)
    # outside the window: still conservative, within one coarse bucket (a factor e^(ln(1e12)/64) ~ 1.54)
    assert low[0, 0] <= el[0, 0] and high[0, 0] >= eh[0, 0]
    assert ev[0, 0] <= v[0, 0] <= ev[0, 0] * np.exp(np.log(1e12) / th.COARSE_BUCKETS) * (1 + 1e-9)


def test_pilot_window_brackets_full_study_ranks():
    """Windows from a pilot histogram contain the full sample's point and interval order statistics.

    With WINDOW_EPS = 1e-9 per side and 600 cells a miss has probability < 1.2e-6 here, so
    the assertion cannot fail by chance at any practical rate; it fails if the levels or ranks
    of :func:`window` are wrong (e.g. a one-sided bound on the wrong side)."""
    rng = np.random.default_rng(4)
    q, conf, n, n_p = 0.99, 0.99, 20000, 6400
    y = rng.exponential(size=(n, 300, 2))
    counts = th.bucket_counts(y[:n_p], *th.pilot_window((300, 2)))
    lo, hi = th.window(counts, n_p, n_p, n, n, q, conf)
    _, el, eh = _exact(y, n, n, q, conf)
    assert np.all(lo <= el) and np.all(eh < hi)
    true = -np.log(1 - q)
    assert np.all(lo < true) and np.all(true < hi)
    # the upper edge is a high order statistic of the pilot (the 1e-9 bound of the 99.6 % level of
    # 6400 values: near the pilot's maximum, 8.8 +- 1.3 for Exp(1)); the lower one ~3.6. Over 600
    # cells the widest window stays below a factor 4.6, i.e. fine buckets < 0.3 %, 25x narrower
    # than the 99 % interval of the 20000-run quantile (~8 %).
    assert th.fine_rel_width(lo, hi) < 3e-3
    assert th.pilot_runs(n, 1 - q, 64) == 4992  # runs / 4 in whole blocks caps 1 - q's 6400


def test_cli_tail_budget(capsys):
    import json

    from chatterspec.cli import main

    argv = ["calibrate", "so-healthy-low", "--runs", "128", "--tail-budget", "0", "--json", "--no-progress"]
    assert main(argv) == 0
    assert json.loads(capsys.readouterr().out)["tails"]["method"] == "histogram"
    with pytest.raises(SystemExit):
        main(["calibrate", "so-healthy-low", "--tail-budget", "nan"])
