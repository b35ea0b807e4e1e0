"""``chatterspec simulate``: the same seed gives the same rows at any --rate, for every scenario."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import chatterspec as cs
from chatterspec.cli import main
from chatterspec.online.simulated_stream import simulate_blocks
from chatterspec.plants.scenarios import Segment


def _rows(capsys, *argv: str) -> list[str]:
    assert main(["simulate", *argv]) == 0
    return capsys.readouterr().out.splitlines()


def test_same_seed_same_rows_whatever_the_rate(capsys) -> None:
    # --rate sets the block length (rate 0: 1 s blocks; paced: ~5 ms of wall time per block, i.e.
    # 0.2 s of data at 40x and 35 samples at 7x): the rows must not depend on it
    out = {
        rate: _rows(capsys, "eha-leak-major", "--seed", "4", "--duration", "2", "--rate", rate)
        for rate in ("0", "40", "7")
    }
    assert len(out["0"]) == 1 + 2001
    assert out["0"] == out["40"] == out["7"]
    other_seed = _rows(capsys, "eha-leak-major", "--seed", "5", "--duration", "2", "--rate", "0")
    assert other_seed[0] == out["0"][0] and other_seed[1:] != out["0"][1:]


@pytest.mark.parametrize("name", ["eha4-leak-onset", "eha4-healthy", "eha4-imm-analogue"])
def test_nonlinear_scenarios_stream(name: str, capsys) -> None:
    sc = cs.scenario(name)
    rows = _rows(capsys, name, "--rate", "0", "--duration", "0.05")
    header = rows[0].split(",")
    assert header == ["time", *sc.nominal.output_names, *sc.nominal.input_names]
    vals = np.array([[float(c) for c in r.split(",")] for r in rows[1:]])
    assert vals.shape == (round(0.05 / sc.dt) + 1, len(header))
    assert np.isfinite(vals).all()


def test_nonlinear_blocks_follow_the_plant_and_do_not_depend_on_the_block_length() -> None:
    sc = cs.scenario("eha4-leak-onset")
    runs = [list(simulate_blocks(sc, 2, 3.0, block_s=b)) for b in (0.001, 0.37, 5.0)]
    z = [np.concatenate([p[1] for p in parts]) for parts in runs]
    assert all(np.array_equal(z[0], other) for other in z[1:])

    # noise-free check of the state path: with Q = R = 0 the measurement (C = I) is the state, and
    # x(k+1) = f(x(k), u(k)) of the segment active at t_k (the major leak from 2 s on)
    def quiet(model):
        return model.replace(Q=0 * model.Q, R=0 * model.R)

    q = dataclasses.replace(
        sc,
        plant=quiet(sc.plant),
        windows=tuple(Segment(w.start, w.stop, quiet(w.model), w.label) for w in sc.windows),
    )
    (t, zq, u), *_ = list(simulate_blocks(q, 0, 3.0, block_s=10.0))
    seg = q.segment_index(t)
    assert seg[0] != seg[-1]  # both segments are crossed
    x = np.array(q.x0, dtype=float)
    for k in range(t.size - 1):
        assert np.array_equal(zq[k], x)
        x = q.segments[seg[k]].model.transition(x[None], u[k])[0]


@pytest.mark.parametrize("name", ["eha-cl-bulk-25down", "eha4-cl-leak-timeline"])
def test_closed_loop_blocks_do_not_depend_on_the_block_length(name: str) -> None:
    sc = cs.scenario(name)
    z = [np.concatenate([p[1] for p in simulate_blocks(sc, 3, 2.0, block_s=b)]) for b in (0.001, 0.37, 5.0)]
    assert all(np.array_equal(z[0], other) for other in z[1:])
