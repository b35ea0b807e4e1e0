"""Operating tolerances of physical parameters: the band a parameter may take in normal operation.

A real actuator's parameters move in normal operation (the bulk modulus with temperature and
entrained air, viscous friction with oil temperature) while its model stays fixed. A
:class:`Tolerance` declares how far a parameter may move from its nominal value before the
change is a fault; fault decisions on the identified parameters
(:mod:`chatterspec.detection.tolerance_decision`) compare each estimate with its band.

Forms (the ``tolerance`` key of a model file's ``[parameters]`` entry, ``examples/README.md``;
the same text after ``--tolerance NAME=`` on the command line, with a comma for the pairs):

================================ ====================================== =====================
model file                       band                                   kind
================================ ====================================== =====================
``tolerance = "15%"``            nominal * (1 -+ 0.15)                  ``relative``
``tolerance = ["-10%", "+20%"]`` nominal - 10 % .. nominal + 20 %       ``relative``
``tolerance = 3.0e7``            nominal -+ 3e7 (the parameter's unit)  ``absolute``
``tolerance = [1.8e8, 2.3e8]``   1.8e8 .. 2.3e8 (the parameter's unit)  ``limits``
================================ ====================================== =====================

Relative offsets are fractions of ``|nominal|``, so a relative band moves with the nominal value
(e.g. one refitted from healthy data); absolute offsets move with it too; limits stay put. A
negative tolerance, a lower offset above the nominal or an upper one below it, or limits that
exclude the nominal are refused (:class:`~chatterspec.errors.ParameterError`; the model file
reader turns it into :class:`~chatterspec.errors.ModelFileError` naming the file and parameter).
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, Literal

from ..errors import ParameterError

__all__ = ["Tolerance", "parse_tolerance", "tolerance_from_text", "with_tolerances"]

ToleranceKind = Literal["relative", "absolute", "limits"]

_PERCENT = re.compile(r"^\s*(\+-|±|\+/-)?\s*([+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?)\s*%\s*$")


@dataclass(frozen=True)
class Tolerance:
    """The band a parameter may take in normal operation.

    Attributes
    ----------
    kind : {"relative", "absolute", "limits"}
        ``relative``: ``lower`` and ``upper`` are fractions of ``|nominal|`` below and above it;
        ``absolute``: offsets in the parameter's unit; ``limits``: the band's ends themselves.
    lower, upper : float
        Offsets below and above the nominal (>= 0; ``relative``, ``absolute``), or the band's
        lower and upper end (``limits``, in the parameter's unit).
    """

    kind: ToleranceKind
    lower: float
    upper: float

    def __post_init__(self) -> None:
        if self.kind not in ("relative", "absolute", "limits"):
            raise ParameterError(f"tolerance kind must be relative, absolute or limits; got {self.kind!r}")
        lo, hi = float(self.lower), float(self.upper)
        if not (math.isfinite(lo) and math.isfinite(hi)):
            raise ParameterError(f"a tolerance must be finite; got {self.text()}")
        if self.kind == "limits":
            if lo > hi:
                raise ParameterError(
                    f"tolerance limits must be [low, high] with low <= high; got [{lo}, {hi}]"
                )
        elif lo < 0 or hi < 0:
            raise ParameterError(f"a tolerance must be >= 0 on both sides; got {self.text()}")
        object.__setattr__(self, "lower", lo)
        object.__setattr__(self, "upper", hi)

    def band(self, nominal: float) -> tuple[float, float]:
        """``(low, high)``: the band around ``nominal`` in the parameter's unit.

        Raises
        ------
        ParameterError
            Limits that exclude ``nominal``; a relative tolerance of a zero nominal (no band).
        """
        x = float(nominal)
        if self.kind == "limits":
            if not self.lower <= x <= self.upper:
                raise ParameterError(
                    f"tolerance limits [{self.lower:.6g}, {self.upper:.6g}] exclude the nominal value {x:.6g}"
                )
            return self.lower, self.upper
        if self.kind == "relative":
            if x == 0.0 and (self.lower or self.upper):
                raise ParameterError(
                    "a relative tolerance of a parameter whose nominal value is 0 is no band: give an "
                    "absolute one (a number in the parameter's unit)"
                )
            return x - self.lower * abs(x), x + self.upper * abs(x)
        return x - self.lower, x + self.upper

    def text(self) -> str:
        """The model-file value: ``"15%"``, ``["-10%", "+20%"]``, ``3e7`` or ``[1.8e8, 2.3e8]`` (TOML)."""
        if self.kind == "limits":
            return f"[{self.lower!r}, {self.upper!r}]"
        if self.kind == "relative":
            lo, hi = _pct(self.lower), _pct(self.upper)
            return f'"{lo}%"' if lo == hi else f'["-{lo}%", "+{hi}%"]'
        return repr(self.lower) if self.lower == self.upper else f'["-{self.lower!r}", "+{self.upper!r}"]'

    def describe(self, unit: str = "") -> str:
        """``"+-15 %"``, ``"-10 %/+20 %"``, ``"+-3e+07 Pa"`` or ``"[1.8e+08, 2.3e+08] Pa"``."""
        u = f" {unit}" if unit else ""
        if self.kind == "limits":
            return f"[{self.lower:.4g}, {self.upper:.4g}]{u}"
        if self.kind == "relative":
            lo, hi = _pct(self.lower), _pct(self.upper)
            return f"+-{lo} %" if lo == hi else f"-{lo} %/+{hi} %"
        if self.lower == self.upper:
            return f"+-{self.lower:.4g}{u}"
        return f"-{self.lower:.4g}/+{self.upper:.4g}{u}"


def _pct(fraction: float) -> str:
    """``0.15`` -> ``"15"`` (percent, shortest text that reads back to the same fraction)."""
    return f"{100 * fraction:.10g}"


def _percent(text: str) -> tuple[float, bool] | None:
    """``"15%"`` -> ``(0.15, False)``; ``"+-15%"`` -> ``(0.15, True)``; None when not a percentage."""
    m = _PERCENT.match(text)
    if m is None:
        return None
    return float(m.group(2)) / 100.0, m.group(1) is not None


def _number(value: object) -> float | None:
    if isinstance(value, bool) or not isinstance(value, int | float):
        return None
    return float(value)


_FORMS = (
    'a percentage "15%", an absolute offset 3e7 (the parameter\'s unit), relative offsets '
    '["-10%", "+20%"], or limits [low, high] (the parameter\'s unit)'
)


def parse_tolerance(value: object, nominal: float, where: str) -> Tolerance:
    """The :class:`Tolerance` of a model file's ``tolerance`` value (see the module docstring).

    Parameters
    ----------
    value : str, float or list of two
        The TOML value.
    nominal : float
        The parameter's nominal value (its band must contain it).
    where : str
        Prefix of error messages (file and parameter).

    Raises
    ------
    ParameterError
        An unreadable form, a negative tolerance, or one that excludes the nominal.
    """
    tol = _parse(value, where)
    try:
        tol.band(nominal)
    except ParameterError as exc:
        raise ParameterError(f"{where}: {exc}") from None
    return tol


def _parse(value: object, where: str) -> Tolerance:
    try:
        if isinstance(value, str):
            pct = _percent(value)
            if pct is None:
                raise ParameterError(f"cannot read {value!r}")
            x, _ = pct
            if x < 0:
                raise ParameterError(f"a tolerance must be >= 0; got {value!r}")
            return Tolerance("relative", x, x)
        offset = _number(value)
        if offset is not None:
            if offset < 0:
                raise ParameterError(f"a tolerance must be >= 0; got {offset!r}")
            return Tolerance("absolute", offset, offset)
        if isinstance(value, list | tuple) and len(value) == 2:
            a, b = value
            na, nb = _number(a), _number(b)
            if na is not None and nb is not None:
                return Tolerance("limits", na, nb)
            if isinstance(a, str) and isinstance(b, str):
                pa, pb = _percent(a), _percent(b)
                if pa is not None and pb is not None:
                    return _offsets("relative", pa[0], pb[0], value)
                fa, fb = _float(a), _float(b)
                if fa is not None and fb is not None:
                    return _offsets("absolute", fa, fb, value)
            raise ParameterError(f"cannot read {value!r}")
        raise ParameterError(f"cannot read {value!r}")
    except ParameterError as exc:
        raise ParameterError(f"{where}: tolerance: {exc}; use {_FORMS}") from None


def _float(text: str) -> float | None:
    try:
        return float(text)
    except ValueError:
        return None


def _offsets(kind: ToleranceKind, below: float, above: float, value: object) -> Tolerance:
    """Signed offsets ``[-a, +b]`` -> ``Tolerance(kind, a, b)``; a lower offset above the nominal or an
    upper one below it excludes the nominal."""
    if below > 0 or above < 0:
        raise ParameterError(
            f"{value!r} excludes the nominal value: the first offset must be <= 0 and the second >= 0"
        )
    return Tolerance(kind, -below, above)


def tolerance_from_text(text: str, nominal: float, where: str) -> Tolerance:
    """A command-line tolerance (``--tolerance NAME=SPEC``): ``15%``, ``3e7``, ``-10%,+20%``, ``1.8e8,2.3e8``.

    Parameters
    ----------
    text : str
        The SPEC part (a comma separates the two ends of a pair).
    nominal : float
        The parameter's nominal value.
    where : str
        Prefix of error messages.
    """
    parts = [p.strip() for p in str(text).split(",")]
    if len(parts) == 1:
        value: object = parts[0] if _percent(parts[0]) is not None else _float(parts[0])
        if value is None:
            value = parts[0]
    elif len(parts) == 2 and all(_percent(p) is not None for p in parts):
        value = parts
    elif len(parts) == 2 and all(_float(p) is not None for p in parts):
        lo, hi = (float(p) for p in parts)
        # signed offsets read as limits only when they are not offsets around the nominal
        value = [str(lo), str(hi)] if parts[0].startswith("-") and parts[1].startswith("+") else [lo, hi]
    else:
        value = text
    return parse_tolerance(value, nominal, where)


def with_tolerances(model: Any, tolerances: Mapping[str, Tolerance | str]) -> Any:
    """A copy of ``model`` whose parameter map gives the parameters in ``tolerances`` those tolerances.

    Parameters
    ----------
    model : LinearModel
        A model with a parameter map (:mod:`chatterspec.plants.parameters`).
    tolerances : mapping of str to Tolerance or str
        Parameter name -> :class:`Tolerance` or its command-line text (``"15%"``, ``"3e7"``,
        ``"-10%,+20%"``, ``"1.8e8,2.3e8"``).

    Raises
    ------
    ParameterError
        The model declares no parameters, an unknown name, or a bad tolerance.
    """
    pm = getattr(model, "parameter_map", None)
    if pm is None:
        raise ParameterError(
            f"{getattr(model, 'name', 'the model')!r} declares no physical parameters, so it has no "
            "parameter to give a tolerance (a model file's [parameters] table, examples/README.md)"
        )
    return model.replace(parameter_map=pm.with_tolerances(tolerances))
