"""Input signals: the chirp's phase (docs/design.md C9)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from chatterspec.errors import NonFiniteError, ParameterError
from chatterspec.plants.scenarios import scenario
from chatterspec.plants.signals import Chirp


def _reference(t: np.ndarray, f0: float, f1: float, t1: float, amp: float, phase_rad: float) -> np.ndarray:
    """Closed form of a linear chirp, written out (not scipy): phase 2 pi (f0 t + k t^2 / 2)."""
    k = (f1 - f0) / t1
    return amp * np.cos(2 * np.pi * (f0 * t + 0.5 * k * t**2) + phase_rad)


def test_default_chirp_is_the_cosine_and_unchanged() -> None:
    t = np.arange(4001) * 1e-3
    c = Chirp(10.0, 100.0, 4.0, 300.0)
    np.testing.assert_allclose(c.sample(t), _reference(t, 10, 100, 4, 300, 0.0), atol=1e-9)
    assert c.sample(np.zeros(1))[0] == pytest.approx(300.0)  # the step at t = 0 of the EHA scenarios
    assert c.describe() == "linear chirp 10->100 Hz over 4 s, amplitude 300"


@pytest.mark.parametrize("phase_deg", [-90.0, 45.0])
def test_chirp_phase(phase_deg: float) -> None:
    t = np.arange(4001) * 1e-3
    c = Chirp(10.0, 100.0, 4.0, 300.0, phase_deg=phase_deg)
    np.testing.assert_allclose(c.sample(t), _reference(t, 10, 100, 4, 300, np.deg2rad(phase_deg)), atol=1e-9)


def test_sine_chirp_starts_at_rest() -> None:
    s = Chirp.sine(10.0, 100.0, 4.0, 300.0)
    assert s.phase_deg == -90.0
    assert abs(s.sample(np.zeros(1))[0]) < 1e-9
    assert "sine" in s.describe()
    with pytest.raises(NonFiniteError):
        Chirp(phase_deg=float("nan"))


def test_eha_scenarios_keep_the_cosine_and_accept_a_sine() -> None:
    sc = scenario("eha-friction-major")
    assert sc.input.phase_deg == 0.0
    alt = dataclasses.replace(sc, input=Chirp.sine())
    u = alt.input.sample(np.arange(3) * sc.dt)
    assert u[0] == pytest.approx(0.0, abs=1e-9) and u[1] > 0


def test_repeat_repeats_the_signal_with_its_period() -> None:
    from chatterspec.plants.signals import Chirp, Repeat

    chirp = Chirp(10.0, 100.0, 4.0, 300.0)
    rep = Repeat(chirp, 4.0)
    t = np.arange(0.0, 12.0, 1e-3)
    np.testing.assert_array_equal(rep.sample(t), chirp.sample(np.mod(t, 4.0)))
    assert "repeated every 4 s" in rep.describe()
    with pytest.raises(ParameterError):
        Repeat(chirp, 0.0)
