"""Monte Carlo engine: chunk planning, determinism across executors, bad input."""

from __future__ import annotations

import numpy as np
import pytest

from chatterspec.errors import ChatterspecError, ParameterError
from chatterspec.montecarlo import BLOCK, block_generator, plan_chunks, run_study, seed_label
from chatterspec.studies.detection_rates import false_alarm_study


class _Draws:
    """Sum of per-realization draws: any chunking mistake changes the float sum."""

    def run_chunk(self, first_run, runs, seed):
        out = []
        for r in range(first_run, first_run + runs):
            b = r // BLOCK
            out.append(block_generator(seed, b).standard_normal(BLOCK)[r - b * BLOCK])
        return np.array(out)

    def reduce(self, acc, part):
        return part if acc is None else np.concatenate([acc, part])


def test_plan_chunks_aligned_to_blocks():
    chunks = plan_chunks(1000, 100)
    assert all(c.first_run % BLOCK == 0 for c in chunks)
    assert sum(c.runs for c in chunks) == 1000
    assert [c.index for c in chunks] == list(range(len(chunks)))


def test_same_seed_same_draws_whatever_chunking():
    a = run_study(_Draws(), 300, seed=7, chunk_runs=64, progress=False)
    b = run_study(_Draws(), 300, seed=7, chunk_runs=256, progress=False)
    np.testing.assert_array_equal(a, b)
    assert a.shape == (300,)


def test_seed_label_is_the_int_of_an_integer_seed_and_none_otherwise():
    assert [seed_label(s) for s in (7, np.int64(7), np.uint32(7))] == [7, 7, 7]
    assert all(type(seed_label(s)) is int for s in (7, np.int64(7)))
    assert [seed_label(s) for s in (None, np.random.SeedSequence(7), np.random.default_rng(7))] == [None] * 3


@pytest.mark.parametrize("bad", [0, -3])
def test_runs_must_be_positive(bad):
    with pytest.raises(ParameterError, match="runs"):
        run_study(_Draws(), bad, seed=0)


def test_workers_must_be_positive():
    with pytest.raises(ParameterError, match="workers"):
        run_study(_Draws(), 10, seed=0, workers=0)


def _small_far(**kw):
    return false_alarm_study(
        "so-healthy-low", alpha=(1e-2,), runs=130, seed=11, chunk_runs=64, progress=False, **kw
    ).to_dict()


def test_identical_for_one_two_workers_and_dask():
    """Same seed -> identical results for 1 worker, 2 local processes and a local Dask cluster."""
    serial = _small_far()
    assert _small_far(workers=2) == serial
    dd = pytest.importorskip("dask.distributed")
    with dd.LocalCluster(
        n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None, host="127.0.0.1"
    ) as cluster:
        assert _small_far(scheduler=cluster.scheduler_address) == serial


def test_unreachable_scheduler_fails_with_a_bounded_wait_and_runs_nothing(monkeypatch):
    """No scheduler listens: one connection attempt with chatterspec's short timeout (not dask's
    default), no chunk computed (no silent local fallback), a ChatterspecError naming the address."""
    dd = pytest.importorskip("dask.distributed")
    from chatterspec import montecarlo

    calls = []
    real_client = dd.Client

    def client(*args, **kwargs):
        calls.append(kwargs.get("timeout"))
        return real_client(*args, **kwargs)

    class NoChunks(_Draws):
        def run_chunk(self, first_run, runs, seed):
            pytest.fail("a chunk ran although the scheduler is unreachable")

    monkeypatch.setattr(dd, "Client", client)
    with pytest.raises(ChatterspecError, match=r"cannot reach the Dask scheduler at 'tcp://127.0.0.1:9'"):
        run_study(NoChunks(), 10, seed=0, scheduler="tcp://127.0.0.1:9")
    assert calls == [f"{montecarlo.DASK_CONNECT_TIMEOUT_S}s"]
    assert montecarlo.DASK_CONNECT_TIMEOUT_S <= 10  # dask's own default connect timeout is 30 s
