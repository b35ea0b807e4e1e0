"""Operating tolerances of declared parameters: the forms, the bands, refusals, model files, CLI text."""

from __future__ import annotations

from pathlib import Path

import pytest

from chatterspec.cli import main
from chatterspec.errors import ModelFileError, ParameterError
from chatterspec.plants.modelfile import load_model
from chatterspec.plants.models import eha_linear
from chatterspec.plants.parameters import Tolerance, parse_tolerance, tolerance_from_text, with_tolerances

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
BE = 2.07e8


@pytest.mark.parametrize(
    ("value", "band"),
    [
        ("15%", (0.85 * BE, 1.15 * BE)),
        ("+-15 %", (0.85 * BE, 1.15 * BE)),
        (["-10%", "+20%"], (0.9 * BE, 1.2 * BE)),
        (3e7, (BE - 3e7, BE + 3e7)),
        (["-3e7", "+5e7"], (BE - 3e7, BE + 5e7)),
        ([1.8e8, 2.3e8], (1.8e8, 2.3e8)),
        ("0%", (BE, BE)),
    ],
)
def test_forms_give_their_band(value: object, band: tuple[float, float]) -> None:
    tol = parse_tolerance(value, BE, "t")
    assert tol.band(BE) == pytest.approx(band, rel=1e-12)
    # the model-file text reads back to the same tolerance
    import tomllib

    again = parse_tolerance(tomllib.loads(f"x = {tol.text()}")["x"], BE, "t")
    assert again == tol


@pytest.mark.parametrize(
    ("value", "why"),
    [
        ("-15%", ">= 0"),
        (-3e7, ">= 0"),
        (["+5%", "+20%"], "excludes the nominal"),
        (["-10%", "-5%"], "excludes the nominal"),
        ([2.1e8, 2.3e8], "exclude the nominal"),
        ([2.3e8, 1.8e8], "low <= high"),
        ("15", "cannot read"),
        ({"lo": 1}, "cannot read"),
    ],
)
def test_bad_tolerances_are_refused(value: object, why: str) -> None:
    with pytest.raises(ParameterError, match=why):
        parse_tolerance(value, BE, "bulk_modulus")


def test_relative_tolerance_of_a_zero_nominal_is_refused() -> None:
    with pytest.raises(ParameterError, match="absolute"):
        Tolerance("relative", 0.1, 0.1).band(0.0)
    assert Tolerance("absolute", 1.0, 2.0).band(0.0) == (-1.0, 2.0)


def test_command_line_text() -> None:
    assert tolerance_from_text("15%", BE, "t").band(BE) == pytest.approx((0.85 * BE, 1.15 * BE))
    assert tolerance_from_text("-10%,+20%", BE, "t").band(BE) == pytest.approx((0.9 * BE, 1.2 * BE))
    assert tolerance_from_text("1.8e8,2.3e8", BE, "t").band(BE) == pytest.approx((1.8e8, 2.3e8))
    assert tolerance_from_text("-3e7,+5e7", BE, "t").band(BE) == pytest.approx((BE - 3e7, BE + 5e7))
    assert tolerance_from_text("3e7", BE, "t").describe("Pa") == "+-3e+07 Pa"
    model = with_tolerances(eha_linear(), {"bulk_modulus": "15%", "friction": "-10%,+30%"})
    pm = model.parameter_map
    assert pm.has_tolerances and pm.parameter("bulk_modulus").band == pytest.approx((0.85 * BE, 1.15 * BE))
    assert pm.parameter("friction").tolerance.describe() == "-10 %/+30 %"
    assert pm.parameter("leakage").tolerance is None
    with pytest.raises(ParameterError, match="no parameter 'bulk'"):
        with_tolerances(eha_linear(), {"bulk": "15%"})


def test_model_file_tolerances_round_trip(tmp_path: Path) -> None:
    text = (EXAMPLES / "eha_model.toml").read_text()
    text = text.replace('unit = "Pa",', 'unit = "Pa", tolerance = "15%",')
    text = text.replace('unit = "N s/m",', 'unit = "N s/m", tolerance = ["-10%", "+30%"],')
    path = tmp_path / "m.toml"
    path.write_text(text)
    pm = load_model(path).model.parameter_map
    assert pm.parameter("bulk_modulus").band == pytest.approx((0.85 * BE, 1.15 * BE))
    assert pm.parameter("friction").band == pytest.approx((0.9 * 2144.0, 1.3 * 2144.0))
    from chatterspec.plants.modelfile import write_model_toml

    spec = load_model(path)
    out = write_model_toml(tmp_path / "again.toml", spec.model, spec.psi)
    again = load_model(out).model.parameter_map
    assert [p.tolerance for p in again.parameters] == [p.tolerance for p in pm.parameters]


@pytest.mark.parametrize(
    ("spec", "why"),
    [
        ('tolerance = "-15%"', "bulk_modulus: tolerance: a tolerance must be >= 0"),
        ("tolerance = [2.1e8, 2.3e8]", r"exclude the nominal value 2.07e\+08"),
        ("tolerance = true", "cannot read"),
    ],
)
def test_model_file_refuses_bad_tolerance_naming_file_and_parameter(
    tmp_path: Path, spec: str, why: str
) -> None:
    text = (EXAMPLES / "eha_model.toml").read_text().replace('unit = "Pa",', f'unit = "Pa", {spec},')
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(ModelFileError, match=why) as exc:
        load_model(path)
    assert "bad.toml" in str(exc.value) and "[parameters] bulk_modulus" in str(exc.value)


def test_cli_refuses_bad_tolerance_in_one_line(capsys: pytest.CaptureFixture[str]) -> None:
    argv = ["monitor", str(EXAMPLES / "eha_model.toml"), "--data", str(EXAMPLES / "eha_data.csv")]
    assert main([*argv, "--tolerance", "bulk_modulus=-15%"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and ">= 0" in err[0]
    assert main([*argv, "--tolerance", "bulk_modulus"]) == 2
    assert "NAME=SPEC" in capsys.readouterr().err
    assert main([*argv, "--tolerance", "bulk=15%", "--alpha", "0.001"]) == 2
    assert "no parameter 'bulk'" in capsys.readouterr().err
    assert main([*argv, "--tolerance", "bulk_modulus=15%", "--alpha", "0.001"]) == 2
    assert "--false-alarms-per-hour" in capsys.readouterr().err
