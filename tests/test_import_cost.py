"""`import chatterspec` and the CLI parser stay light, so bad arguments fail at once."""

from __future__ import annotations

import subprocess
import sys

import chatterspec
from chatterspec.cli.diagnose import METHOD_NAMES, ROUTE_SET, WARMUP_S
from chatterspec.cli.estimate import FILTERS as CLI_FILTERS
from chatterspec.cli.power import FAMILY_NAMES
from chatterspec.studies.budget_diagnosis import ALL_METHODS, DEFAULT_WARMUP_S, ROUTE_RULE_PARAMETERS
from chatterspec.studies.detection_rates import POWER_FAMILIES
from chatterspec.studies.estimation import FILTERS


def test_parser_and_package_import_do_not_load_scipy() -> None:
    code = (
        "import sys, chatterspec; from chatterspec.cli import build_parser; build_parser(); "
        "print(sorted(m for m in ('scipy', 'matplotlib', 'rerun', 'numba') if m in sys.modules))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"


def test_lazy_names_resolve_and_unknown_names_raise() -> None:
    for name in chatterspec.__all__:
        assert getattr(chatterspec, name) is not None
    assert "simulate" in dir(chatterspec)
    try:
        chatterspec.no_such_name  # noqa: B018
    except AttributeError as exc:
        assert "no_such_name" in str(exc)
    else:  # pragma: no cover
        raise AssertionError("unknown attribute did not raise")


def test_power_family_names_match_the_study() -> None:
    assert FAMILY_NAMES == tuple(POWER_FAMILIES)


def test_estimate_filter_names_match_the_study() -> None:
    assert CLI_FILTERS == FILTERS


def test_diagnose_route_names_and_warmup_match_the_study() -> None:
    assert METHOD_NAMES == ALL_METHODS
    assert ROUTE_SET == ROUTE_RULE_PARAMETERS
    assert WARMUP_S == DEFAULT_WARMUP_S
