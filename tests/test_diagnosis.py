"""``chatterspec diagnose`` with the chattering route: the chattering diagnosis on the same
realizations as the mode-based methods, its calibration, the comparison table and the CLI."""

from __future__ import annotations

import json

import numpy as np
import pytest
import scipy.stats

import chatterspec as cs
from chatterspec.detection.spectral import STFTConfig
from chatterspec.errors import ParameterError
from chatterspec.studies.diagnosis import (
    calibrate_for_diagnosis,
    diagnose_chattering,
    healthy_version,
)

ALPHA = 0.01  # per-frame level of the test calibrations (small calibrations: keep alpha * frames >> 1)


@pytest.fixture(scope="module")
def onset_calibration():  # type: ignore[no-untyped-def]
    # eha4-leak-onset: 4 s, healthy until 2 s, major leakage after; 80 calibration runs (+ 200 pilot runs)
    return calibrate_for_diagnosis(cs.scenario("eha4-leak-onset"), seed=5, runs=80, alpha=ALPHA)


def test_healthy_version_keeps_model_input_and_length() -> None:
    sc = cs.scenario("eha4-leak-timeline")
    h = healthy_version(sc)
    assert h.is_healthy and not sc.is_healthy
    assert h.n_samples == sc.n_samples and h.nominal is sc.nominal and h.input == sc.input


def test_chattering_diagnosis_on_the_leak_onset(onset_calibration) -> None:  # type: ignore[no-untyped-def]
    sc = cs.scenario("eha4-leak-onset")
    runs = 12
    sim = cs.simulate(sc, runs=runs, seed=1)
    thr = onset_calibration.threshold("frame-family-wise")
    res = diagnose_chattering(sim, thr, calibration_info={"source": "test"})
    assert res.onsets == pytest.approx((2.0,))
    # frames of 1 s at a 0.2 s hop whose window ends before 2 s: ends at 1.0, 1.2, ..., 1.8 s
    assert res.healthy_frames_per_run == 5 and res.frames_per_run == 16
    # the major leakage shows on the acceleration channel in every run; the first frame that can see it
    # ends after 2 s, so the causal delay is a positive multiple of the hop, at most one window
    assert res.missed == (0,)
    assert 0.0 < res.detection_median[0] <= res.detection_p90[0] <= 1.0 + 1e-9
    assert res.segments == ("healthy", "leak-major")
    assert res.flagged_channel[1] == "acceleration" and res.flag_fraction[1, 2] > 0.9
    assert 0.0 < res.peak_hz[1] < 50.0
    # false alarms: per run at most 5 frames x 4 channels tests at level alpha each; by the union bound
    # P(run alarm) <= 20 alpha whatever the dependence between overlapping frames. The calibration's
    # 1 - alpha quantile comes from 80 x 16 frames (~ 80 x 4 independent ones, ~3 expected exceedances),
    # so its actual level may be ~3x off: test against a binomial with p = 3 x 20 alpha at 1e-3.
    bound = scipy.stats.binom.ppf(1 - 1e-3, runs, min(1.0, 3 * 20 * ALPHA))
    assert res.false_alarm_runs <= bound
    lo, hi = res.false_alarm_ci
    assert lo <= res.false_alarm_rate <= hi
    doc = res.describe()
    assert doc["method"] == "chattering" and doc["isolation"][1]["flagged_channel"] == "acceleration"
    json.dumps(doc)
    with pytest.raises(ParameterError, match="STFT"):
        diagnose_chattering(sim, thr, config=STFTConfig(window_s=0.5, hop_s=0.1))
    with pytest.raises(ParameterError, match="Threshold"):
        diagnose_chattering(sim, np.ones(3))  # type: ignore[arg-type]


def test_chattering_and_smm_on_the_same_realizations(onset_calibration) -> None:  # type: ignore[no-untyped-def]
    from chatterspec.figures.plot_diagnosis import DIAGNOSIS_HEADER, diagnosis_rows, diagnosis_table_figure
    from chatterspec.studies.diagnosis import diagnose_modes

    # eha4-leak-timeline shares eha4-leak-onset's nominal model: the per-frame threshold applies
    sim = cs.simulate(cs.scenario("eha4-leak-timeline"), runs=3, seed=4)
    chat = diagnose_chattering(sim, onset_calibration.threshold("frame-family-wise"))
    keep: dict = {}
    (smm,) = diagnose_modes(sim, ("smm",), keep=keep)
    assert chat.onsets == pytest.approx((3.0, 6.0)) and smm.onsets == pytest.approx((3.0, 6.0))
    assert chat.missed[0] == 0 and chat.flagged_channel[1] == "acceleration"
    # the minor leakage is still flagged when the major one starts: 6 s is not a new detection
    assert chat.in_alarm_at_onset[1] == 3
    t, mu, modes = keep["smm"]
    assert mu.shape == (3, sim.t.size - 1, 3) and t.shape == (sim.t.size - 1,) and modes[0] == "normal"
    header, rows = diagnosis_rows([chat, smm])
    assert header == DIAGNOSIS_HEADER and len(rows) == 4
    assert rows[0][0] == "chattering" and rows[2][0] == "smm" and "acceleration" in rows[0][4]
    assert "leak-minor" in rows[2][4]
    fig = diagnosis_table_figure([chat, smm], title="test")
    assert len(fig.axes) == 1
    import matplotlib.pyplot as plt

    plt.close(fig)


def test_diagnose_command_with_the_chattering_route(tmp_path, capsys, onset_calibration) -> None:  # type: ignore[no-untyped-def]
    from chatterspec.cli import main

    path = onset_calibration.save(tmp_path / "cal.npz")
    argv = [
        "diagnose",
        "eha4-leak-onset",
        "--runs",
        "2",
        "--seed",
        "3",
        "--calibration",
        str(path),
        "--per-record",
    ]
    assert main([*argv, "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert [m["method"] for m in doc["methods"]] == ["chattering"]
    assert doc["methods"][0]["calibration"]["source"] == str(path)
    assert main(argv) == 0
    out = capsys.readouterr().out
    assert "chattering" in out and "acceleration" in out
    # a calibration of another model is refused with the reason
    from chatterspec.studies.calibration.thresholds import calibrate

    other = calibrate("eha-healthy", alpha=0.01, runs=20, seed=0)
    bad = other.save(tmp_path / "other.npz")
    assert (
        main(["diagnose", "eha4-leak-onset", "--runs", "1", "--calibration", str(bad), "--per-record"]) == 2
    )
    assert "recalibrate" in capsys.readouterr().err
    assert main(["diagnose", "eha4-leak-onset", "--methods", "chattering,foo"]) == 2
    assert "subset of chattering,smm,imm,innovation" in capsys.readouterr().err
    assert main(["diagnose", "eha4-leak-onset", "--methods", "smm"]) == 2
    assert "does not support --methods smm" in capsys.readouterr().err
    # --record is checked before anything is computed
    assert main(["diagnose", "eha4-leak-onset", "--record", str(tmp_path / "x.txt")]) == 2
    assert ".rrd" in capsys.readouterr().err


def test_diagnose_record_puts_modes_and_chattering_on_one_timeline(tmp_path, onset_calibration) -> None:  # type: ignore[no-untyped-def]
    rr = pytest.importorskip("rerun")
    from rerun.chunk import RrdReader

    from chatterspec.studies.diagnosis import diagnose_modes
    from chatterspec.viewer.recordings import record_diagnosis

    rr.set_strict_mode(True)
    try:
        sim = cs.simulate(cs.scenario("eha4-leak-timeline"), runs=1, seed=6)
        keep: dict = {}
        diagnose_modes(sim, ("smm",), keep=keep)
        path = record_diagnosis(
            tmp_path / "d.rrd", sim, onset_calibration.threshold("frame-family-wise"), keep
        )
    finally:
        rr.set_strict_mode(False)
    reader = RrdReader(path)
    summary = reader.store().summary()  # needs the footer: the file is complete
    assert "/spectrogram/" in summary and "/modes/smm/" in summary
    t, mu, modes = keep["smm"]
    for j, mode in enumerate(modes):
        times, values = [], []
        for chunk in reader.stream().filter(content=f"/modes/smm/{mode}", is_static=False).to_chunks():
            rb = chunk.to_record_batch()
            times.extend(rb.column("time").cast("int64").to_pylist())
            values.extend(v[0] for v in rb.column("Scalars:scalars").to_pylist())
        order = np.argsort(times)
        # the same timeline as the monitor: integer ns of the sample times (to_ns rounds)
        np.testing.assert_array_equal(np.asarray(times)[order], np.round(t * 1e9).astype(np.int64))
        np.testing.assert_allclose(np.asarray(values)[order], mu[0, :, j], rtol=0, atol=0)
    # the detection events of the chattering route are in the same file
    events = list(reader.stream().filter(content="/events", is_static=False).to_chunks())
    assert sum(c.num_rows for c in events) >= 1
