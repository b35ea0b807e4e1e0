"""Physical parameters of a linear model: which matrix entries they enter, and how.

Fault identification (:mod:`chatterspec.detection.identification`) estimates a physical
parameter (a leakage coefficient in m^3/(s Pa), a natural frequency in Hz) from the
chattering. For that it must know how the parameter enters the discrete matrices A and B
of eq (1). A :class:`ParameterMap` declares it:

* **parameters**: named physical quantities with a nominal value and a unit; these are
  what identification can estimate;
* **constants**: other named values the formulas use (``dt``, the sampling time in s, is
  always available);
* **entries**: for each entry of A or B that depends on a parameter, a formula (text,
  see :mod:`chatterspec.plants._expressions`), e.g. ``A[3,3] = 1 - dt*bulk_modulus*leakage/volume``;
* **hypotheses**: named sets of parameters that may have changed together (default: one
  hypothesis per parameter).

The catalogue models carry their map (:func:`eha_parameter_map`, :func:`second_order_parameter_map`,
attached by :func:`chatterspec.plants.models.eha_linear` and :func:`~chatterspec.plants.models.second_order`
for explicit Euler); a model file declares one in ``[parameters]``, ``[constants]``,
``[entries]`` and ``[hypotheses]`` (``examples/README.md``), so a user's own model gets
identification without code. :meth:`ParameterMap.check` makes sure the formulas give the
model's own A and B at the nominal values.
"""

from __future__ import annotations

import itertools
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any, Literal, TypeVar, cast

import numpy as np

from ..errors import ChatterspecError, ModelFileError, ParameterError
from ._expressions import BUILTIN_CONSTANTS, FUNCTIONS, Formula, compile_formula, evaluate_formulas
from .tolerances import Tolerance, parse_tolerance, tolerance_from_text

if TYPE_CHECKING:  # pragma: no cover
    from .linear_model import LinearModel

__all__ = [
    "NO_FAULT",
    "UNEXPLAINED",
    "Hypothesis",
    "MatrixEntry",
    "ParameterMap",
    "PhysicalParameter",
    "eha_parameter_map",
    "second_order_parameter_map",
]

#: Name of the hypothesis "nothing changed" (reserved).
NO_FAULT = "no fault"
#: Name selected when the model's data reject "no fault" and every declared hypothesis (reserved).
UNEXPLAINED = "unexplained"

#: Up to this many parameters every combination is a hypothesis (:meth:`ParameterMap.combinations`).
MAX_ALL_COMBINATIONS = 6

_NAME = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")
_ENTRY = re.compile(r"^\s*([AB])\s*\[\s*(\d+)\s*,\s*(\d+)\s*\]\s*$")


@dataclass(frozen=True)
class PhysicalParameter:
    """A named physical parameter with its nominal value.

    Attributes
    ----------
    name : str
        Identifier used in formulas and hypotheses (letters, digits, ``_``).
    value : float
        Nominal value (the value in the nominal model), in ``unit``.
    unit : str
        Unit of ``value`` and of every estimate (e.g. ``"m^3/(s Pa)"``, ``"Hz"``).
    description : str
        Human-readable meaning.
    tolerance : Tolerance or None
        The band the parameter may take in normal operation
        (:mod:`chatterspec.plants.tolerances`); None: none declared.
    """

    name: str
    value: float
    unit: str = ""
    description: str = ""
    tolerance: Tolerance | None = None

    @property
    def band(self) -> tuple[float, float] | None:
        """``(low, high)`` of :attr:`tolerance` around :attr:`value` (None without a tolerance)."""
        return None if self.tolerance is None else self.tolerance.band(self.value)


@dataclass(frozen=True)
class Hypothesis:
    """A fault hypothesis: the parameters that may have changed (all others keep their nominal value).

    Attributes
    ----------
    name : str
    parameters : tuple of str
    """

    name: str
    parameters: tuple[str, ...]


@dataclass(frozen=True)
class MatrixEntry:
    """One entry of the discrete A or B written as a formula of parameters and constants.

    Attributes
    ----------
    matrix : {"A", "B"}
    row, col : int
        0-based indices (written 1-based, ``A[row+1,col+1]``, in files and messages).
    formula : Formula
    """

    matrix: Literal["A", "B"]
    row: int
    col: int
    formula: Formula

    @property
    def label(self) -> str:
        """``"A[3,3]"``: the entry, 1-based as in files and messages."""
        return f"{self.matrix}[{self.row + 1},{self.col + 1}]"


_Named = TypeVar("_Named", bound="PhysicalParameter | Hypothesis")


def _named(items: Sequence[_Named], name: str, missing: str) -> _Named:
    """The item of ``items`` called ``name``; :class:`ParameterError` with ``missing`` otherwise."""
    for item in items:
        if item.name == name:
            return item
    raise ParameterError(missing)


@dataclass(frozen=True, eq=False)
class ParameterMap:
    """How named physical parameters enter the discrete matrices A and B of a linear model.

    Parameters
    ----------
    parameters : sequence of PhysicalParameter
        The parameters identification may estimate.
    entries : sequence of MatrixEntry
        Formulas of the entries of A and B that depend on parameters (entries not listed
        keep the model's value).
    constants : mapping of str to float
        Other named values of the formulas (e.g. ``mass``); ``dt`` is supplied by the model.
    hypotheses : sequence of Hypothesis, optional
        Named parameter sets; default one hypothesis per parameter, named after it.

    Raises
    ------
    ParameterError
        On a duplicate or invalid name, an entry listed twice, a formula reading a name
        that is neither a parameter nor a constant, a hypothesis naming a parameter the
        map does not have, or a parameter that enters no entry.
    """

    parameters: tuple[PhysicalParameter, ...]
    entries: tuple[MatrixEntry, ...]
    constants: Mapping[str, float] = field(default_factory=dict)
    hypotheses: tuple[Hypothesis, ...] = ()

    def __post_init__(self) -> None:
        params = tuple(self.parameters)
        names = [p.name for p in params]
        consts = {str(k): float(v) for k, v in dict(self.constants).items()}
        for n in (*names, *consts):
            if not _NAME.match(n) or n in FUNCTIONS or n in BUILTIN_CONSTANTS:
                raise ParameterError(f"{n!r} cannot name a parameter or constant (use letters, digits, _)")
        if n_dup := sorted({n for n in names + list(consts) if (names + list(consts)).count(n) > 1}):
            raise ParameterError(f"names declared twice among parameters and constants: {n_dup}")
        if "dt" in names:
            raise ParameterError("'dt' is the model's sampling time, not a parameter")
        for p in params:
            if not np.isfinite(p.value):
                raise ParameterError(f"parameter {p.name!r} needs a finite nominal value; got {p.value!r}")
            if p.tolerance is not None:
                try:
                    p.tolerance.band(p.value)
                except ParameterError as exc:
                    raise ParameterError(f"parameter {p.name!r}: {exc}") from None
        known = set(names) | set(consts) | {"dt"} | set(BUILTIN_CONSTANTS)
        seen: set[tuple[str, int, int]] = set()
        used: set[str] = set()
        for e in self.entries:
            key = (e.matrix, e.row, e.col)
            if key in seen:
                raise ParameterError(f"entry {e.label} is declared twice")
            seen.add(key)
            unknown = sorted(e.formula.names - known)
            if unknown:
                raise ParameterError(
                    f"entry {e.label} = {e.formula.text!r} reads {unknown}, which are neither parameters "
                    f"({', '.join(names) or 'none'}) nor constants ({', '.join(['dt', *consts])})"
                )
            used |= e.formula.names
        for name in names:
            if name not in used:
                raise ParameterError(
                    f"parameter {name!r} enters no entry of A or B: declare the entries it enters"
                )
        hyps = tuple(self.hypotheses) or tuple(Hypothesis(p, (p,)) for p in names)
        hnames = [h.name for h in hyps]
        if len(set(hnames)) != len(hnames):
            raise ParameterError(f"hypothesis names must be distinct; got {hnames}")
        for h in hyps:
            if h.name in (NO_FAULT, UNEXPLAINED):
                raise ParameterError(f"{h.name!r} is reserved; choose another hypothesis name")
            if not h.parameters or len(set(h.parameters)) != len(h.parameters):
                raise ParameterError(
                    f"hypothesis {h.name!r} must list distinct parameters; got {h.parameters}"
                )
            missing = [q for q in h.parameters if q not in names]
            if missing:
                raise ParameterError(
                    f"hypothesis {h.name!r} names parameter(s) {missing} the model does not have; "
                    f"its parameters: {', '.join(names) or 'none'}"
                )
        object.__setattr__(self, "parameters", params)
        object.__setattr__(self, "entries", tuple(self.entries))
        object.__setattr__(self, "constants", consts)
        object.__setattr__(self, "hypotheses", hyps)

    # -- lookup ----------------------------------------------------------------
    @property
    def parameter_names(self) -> tuple[str, ...]:
        """Names of the physical parameters, in table order."""
        return tuple(p.name for p in self.parameters)

    def parameter(self, name: str) -> PhysicalParameter:
        """The parameter called ``name`` (:class:`ParameterError` listing the names otherwise)."""
        names = ", ".join(self.parameter_names)
        return _named(self.parameters, name, f"the model has no parameter {name!r}; its parameters: {names}")

    def hypothesis(self, name: str) -> Hypothesis:
        """The hypothesis called ``name`` (:class:`ParameterError` listing the names otherwise)."""
        names = ", ".join(h.name for h in self.hypotheses)
        return _named(self.hypotheses, name, f"no hypothesis {name!r}; declared: {names}")

    @property
    def has_tolerances(self) -> bool:
        """Whether any parameter declares an operating tolerance."""
        return any(p.tolerance is not None for p in self.parameters)

    def with_tolerances(self, tolerances: Mapping[str, Tolerance | str]) -> ParameterMap:
        """A copy whose parameters named in ``tolerances`` get that tolerance (the others keep theirs).

        Parameters
        ----------
        tolerances : mapping of str to Tolerance or str
            Parameter name -> a :class:`~chatterspec.plants.tolerances.Tolerance` or its command-line
            text (``"15%"``, ``"3e7"``, ``"-10%,+20%"``, ``"1.8e8,2.3e8"``).

        Raises
        ------
        ParameterError
            An unknown parameter (the message lists the model's), an unreadable tolerance, or one
            that excludes the nominal value.
        """
        new = dict(tolerances)
        for name in new:
            self.parameter(name)
        params = []
        for p in self.parameters:
            tol = new.get(p.name, p.tolerance)
            if isinstance(tol, str):
                tol = tolerance_from_text(tol, p.value, f"tolerance of {p.name}")
            params.append(replace(p, tolerance=tol))
        return ParameterMap(tuple(params), self.entries, self.constants, self.hypotheses)

    def with_hypotheses(self, hypotheses: Sequence[Hypothesis | str | Sequence[str]]) -> ParameterMap:
        """A copy with other hypotheses: ``Hypothesis`` objects, parameter names, or lists of names.

        A string is a one-parameter hypothesis named after the parameter; a list of names is a
        combination named ``"a+b"``. Unknown parameter names raise :class:`ParameterError`.
        """
        hyps = []
        for h in hypotheses:
            if isinstance(h, Hypothesis):
                hyps.append(h)
            elif isinstance(h, str):
                hyps.append(Hypothesis(h, (h,)))
            else:
                names = tuple(str(x) for x in h)
                hyps.append(Hypothesis("+".join(names), names))
        return ParameterMap(self.parameters, self.entries, self.constants, tuple(hyps))

    def combinations(self) -> tuple[Hypothesis, ...]:
        """The declared hypotheses, then every other combination of the parameters (joint faults).

        A combination is named ``"a+b"`` (table order) unless a declared hypothesis has the same
        parameters (its name is kept). With more than :data:`MAX_ALL_COMBINATIONS` parameters only the
        single parameters, the pairs and the set of all are added (``2^P - 1`` would grow too fast).
        Sorted by size, then in table order, after the declared ones.
        """
        names = self.parameter_names
        declared = {frozenset(h.parameters) for h in self.hypotheses}
        if len(names) <= MAX_ALL_COMBINATIONS:
            sizes: Sequence[int] = range(1, len(names) + 1)
        else:
            sizes = sorted({1, 2, len(names)})
        extra = [
            Hypothesis("+".join(c), c)
            for k in sizes
            for c in itertools.combinations(names, k)
            if frozenset(c) not in declared
        ]
        return (*self.hypotheses, *extra)

    # -- evaluation --------------------------------------------------------------
    def values(self, dt: float, overrides: Mapping[str, object] | None = None) -> dict[str, object]:
        """Every name of the formulas: constants, ``dt``, nominal parameters updated by ``overrides``."""
        out: dict[str, object] = {**self.constants, "dt": float(dt)}
        out.update({p.name: p.value for p in self.parameters})
        for k, v in (overrides or {}).items():
            self.parameter(k)
            out[k] = v
        return out

    def evaluate(self, dt: float, overrides: Mapping[str, object] | None = None) -> np.ndarray:
        """``(..., n_entries)``: every declared entry at the nominal values updated by ``overrides``.

        Parameters
        ----------
        dt : float
            Sampling time of the model (s).
        overrides : mapping, optional
            Parameter name -> value or array of values (arrays broadcast against each other).
        """
        vals = self.values(dt, overrides)
        cols = [np.asarray(e.formula(vals), dtype=float) for e in self.entries]
        shape = np.broadcast_shapes(*(c.shape for c in cols)) if cols else ()
        return np.stack([np.broadcast_to(c, shape) for c in cols], axis=-1) if cols else np.empty((0,))

    def entry_values(self, indices: Sequence[int], values: Mapping[str, object]) -> list[np.ndarray]:
        """The formulas of the entries ``indices`` (into :attr:`entries`) evaluated with ``values`` (every
        name they read, e.g. :meth:`values` with arrays for some parameters), in one scope: the numbers
        of :meth:`evaluate`'s columns, with less overhead per call."""
        return evaluate_formulas([self.entries[k].formula for k in indices], values)

    def depends(self, parameters: Sequence[str]) -> np.ndarray:
        """``(n_entries,)`` bool: the entries whose formula reads any of ``parameters``."""
        ps = set(parameters)
        return np.array([bool(e.formula.names & ps) for e in self.entries], dtype=bool)

    def check(self, model: LinearModel, *, rtol: float = 1e-9) -> None:
        """Raise :class:`ParameterError` unless the formulas give ``model``'s A and B at the nominal values.

        Also checks that every entry lies inside A (n x n) or B (n x p).
        """
        n, p = model.n_states, model.n_inputs
        for e in self.entries:
            rows, cols = (n, n) if e.matrix == "A" else (n, p)
            if not (0 <= e.row < rows and 0 <= e.col < cols):
                raise ParameterError(f"entry {e.label} lies outside {e.matrix} ({rows} x {cols})")
        vals = self.evaluate(model.dt)
        for e, v in zip(self.entries, np.atleast_1d(vals), strict=True):
            M = model.A if e.matrix == "A" else model.B
            have = float(M[e.row, e.col])
            scale = max(abs(have), float(np.max(np.abs(M[e.row]))) * 1e-12, 1e-300)
            if not np.isfinite(v) or abs(float(v) - have) > rtol * scale:
                raise ParameterError(
                    f"entry {e.label} = {e.formula.text!r} gives {float(v):.12g} at the nominal parameter "
                    f"values, but the model's {e.label} is {have:.12g}: the declaration does not describe "
                    "this model (wrong nominal value, constant or formula)"
                )

    def model_with(
        self, model: LinearModel, overrides: Mapping[str, float], name: str | None = None
    ) -> LinearModel:
        """``model`` with its declared entries of A and B evaluated at the parameters ``overrides``.

        The way a model file's ``[parameters]`` and ``[entries]`` build A and B, at other parameter
        values (e.g. a true plant whose bulk modulus is 10 % low); every other entry, C, Q, R and
        ``dt`` are ``model``'s. The result carries this map with the new values as its nominal ones.

        Parameters
        ----------
        model : LinearModel
            The model the map describes (:meth:`check` holds for it).
        overrides : mapping of str to float
            Parameter name -> value, in the parameter's unit.
        name : str, optional
            The new model's name (default: ``model.name`` with the changed values).

        Raises
        ------
        ParameterError
            An unknown parameter name, a value that is not finite, or one that makes an entry
            non-finite.
        """
        import dataclasses

        vals = {k: float(v) for k, v in overrides.items()}
        for k, v in vals.items():
            self.parameter(k)
            if not np.isfinite(v):
                raise ParameterError(f"parameter {k!r} must be finite; got {v!r}")
        entries = np.atleast_1d(self.evaluate(model.dt, vals))
        A, B = np.array(model.A), np.array(model.B)
        for e, v in zip(self.entries, entries, strict=True):
            if not np.isfinite(v):
                raise ParameterError(f"entry {e.label} = {e.formula.text!r} is not finite at {vals}")
            (A if e.matrix == "A" else B)[e.row, e.col] = float(v)
        params = tuple(dataclasses.replace(p, value=vals.get(p.name, p.value)) for p in self.parameters)
        pmap = ParameterMap(params, self.entries, self.constants, self.hypotheses)
        label = ", ".join(f"{k} = {v:.4g}" for k, v in vals.items())
        return dataclasses.replace(
            model,
            A=A,
            B=B,
            parameter_map=pmap,
            oscillatory_block=None,
            name=name or (f"{model.name} ({label})" if label else model.name),
        )

    def to_toml(self) -> str:
        """The ``[parameters]``, ``[constants]``, ``[entries]`` and ``[hypotheses]`` tables as TOML text."""
        import json

        def num(v: float) -> str:
            return repr(float(v))

        lines = ["[parameters]"]
        for p in self.parameters:
            fields = [f"value = {num(p.value)}", f"unit = {json.dumps(p.unit)}"]
            if p.description:
                fields.append(f"description = {json.dumps(p.description)}")
            if p.tolerance is not None:
                fields.append(f"tolerance = {p.tolerance.text()}")
            lines.append(f"{p.name} = {{ {', '.join(fields)} }}")
        if self.constants:
            lines += ["", "[constants]"] + [f"{k} = {num(v)}" for k, v in self.constants.items()]
        lines += ["", "[entries]"] + [f'"{e.label}" = {json.dumps(e.formula.text)}' for e in self.entries]
        lines += ["", "[hypotheses]"]
        lines += [f"{json.dumps(h.name)} = {json.dumps(list(h.parameters))}" for h in self.hypotheses]
        return "\n".join(lines)


def parse_entry_key(key: str, where: str) -> tuple[Literal["A", "B"], int, int]:
    """``"A[3,3]"`` -> ``("A", 2, 2)`` (1-based in the text, 0-based out)."""
    m = _ENTRY.match(str(key))
    if not m or int(m.group(2)) < 1 or int(m.group(3)) < 1:
        raise ParameterError(f'{where}: entry key {key!r} must look like "A[3,3]" or "B[3,1]" (1-based)')
    return cast(Literal["A", "B"], m.group(1)), int(m.group(2)) - 1, int(m.group(3)) - 1  # (the regex)


def parameter_map_from_tables(
    doc: Mapping[str, Any], where: str, *, continuous: bool = False
) -> ParameterMap | None:
    """Build a :class:`ParameterMap` from a model file's ``[parameters]``, ``[constants]``,
    ``[entries]`` and ``[hypotheses]`` tables (None when the file has no ``[parameters]``).

    With ``continuous=True`` the entry formulas describe the continuous matrices and are
    turned into explicit-Euler discrete entries (``A = I + dt Ac``, ``B = dt Bc``).

    Raises
    ------
    ParameterError
        With ``where`` and the table named, on any malformed declaration.
    """
    raw = doc.get("parameters")
    if raw is None:
        for key in ("entries", "hypotheses"):
            if key in doc:
                raise ParameterError(f"{where}: [{key}] needs a [parameters] table")
        return None
    tables = {}
    for key in ("parameters", "constants", "entries", "hypotheses"):
        value = doc.get(key, {})
        if not isinstance(value, dict):
            raise ParameterError(f"{where}: [{key}] must be a table")
        tables[key] = value
    params = []
    for name, spec in tables["parameters"].items():
        if isinstance(spec, dict):
            unknown = set(spec) - {"value", "unit", "description", "tolerance"}
            if unknown:
                raise ParameterError(
                    f"{where}: [parameters] {name}: unknown key(s) {sorted(unknown)} (keys: value, unit, "
                    "description, tolerance)"
                )
            value, unit, desc = spec.get("value"), spec.get("unit", ""), spec.get("description", "")
        else:
            value, unit, desc = spec, "", ""
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise ParameterError(
                f"{where}: [parameters] {name} needs a numeric value, e.g. "
                f'{name} = {{ value = 1.0, unit = "..." }}; got {value!r}'
            )
        tol = None
        if isinstance(spec, dict) and "tolerance" in spec:
            tol = parse_tolerance(spec["tolerance"], float(value), f"{where}: [parameters] {name}")
        params.append(PhysicalParameter(str(name), float(value), str(unit), str(desc), tol))
    consts = {}
    for name, value in tables["constants"].items():
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise ParameterError(f"{where}: [constants] {name} must be a number; got {value!r}")
        consts[str(name)] = float(value)
    if not tables["entries"]:
        raise ParameterError(
            f"{where}: [entries] is missing: declare the entries of A and B the parameters enter"
        )
    entries = []
    for key, text in tables["entries"].items():
        matrix, row, col = parse_entry_key(key, f"{where}: [entries]")
        formula = compile_formula(text if isinstance(text, str) else "", f"{where}: [entries] {key}")
        if continuous:
            delta = "1 + " if matrix == "A" and row == col else ""
            formula = compile_formula(f"{delta}dt*({formula.text})", f"{where}: [entries] {key}")
        entries.append(MatrixEntry(matrix, row, col, formula))
    hyps = []
    for name, plist in tables["hypotheses"].items():
        if isinstance(plist, str):
            plist = [plist]
        if not isinstance(plist, list) or not all(isinstance(x, str) for x in plist):
            raise ParameterError(
                f"{where}: [hypotheses] {name} must be a list of parameter names; got {plist!r}"
            )
        hyps.append(Hypothesis(str(name), tuple(plist)))
    try:
        return ParameterMap(tuple(params), tuple(entries), consts, tuple(hyps))
    except ParameterError as exc:
        raise ParameterError(f"{where}: {exc}") from None


def model_file_parameter_map(
    doc: Mapping[str, Any], where: str, form: str, method: str
) -> ParameterMap | None:
    """:func:`parameter_map_from_tables` for :func:`chatterspec.plants.modelfile.load_model`: errors
    become :class:`~chatterspec.errors.ModelFileError`; continuous entries need explicit Euler."""
    if form == "continuous" and method != "euler" and "parameters" in doc:
        raise ModelFileError(
            f"{where}: [entries] of a continuous model are discretized with explicit Euler; with "
            "discretization = 'zoh' the discrete entries have no closed form: write [matrices] in "
            "discrete form"
        )
    try:
        return parameter_map_from_tables(doc, where, continuous=form == "continuous")
    except ChatterspecError as exc:
        raise ModelFileError(str(exc)) from None


# --------------------------------------------------------------------------- catalogue models
def _entries(spec: Mapping[str, str], where: str) -> tuple[MatrixEntry, ...]:
    out = []
    for key, text in spec.items():
        matrix, row, col = parse_entry_key(key, where)
        out.append(MatrixEntry(matrix, row, col, compile_formula(text, f"{where} {key}")))
    return tuple(out)


def eha_parameter_map(
    *,
    leakage: float,
    friction: float,
    bulk_modulus: float,
    piston_area: float,
    pump_displacement: float,
    mass: float,
    volume: float,
) -> ParameterMap:
    """Leakage, friction and bulk modulus of the linear EHA (eq 65/67, explicit Euler).

    ``A[2,2] = 1 - dt a/M``, ``A[2,3] = dt Ac/M``, ``A[3,2] = -dt be Ac/V0``,
    ``A[3,3] = 1 - dt be L/V0``, ``B[3,1] = dt be Dp/V0``: leakage L enters A33, friction a
    enters A22, the bulk modulus be enters A32, A33 and B3 jointly (eq 68-70). Hypotheses:
    one per parameter.

    Parameters
    ----------
    leakage, friction, bulk_modulus : float
        Nominal values of the identifiable parameters: L in m^3/(s Pa), a in N s/m, be in Pa.
    piston_area, pump_displacement, mass, volume : float
        The other Table 1 values, constants of the formulas: Ac in m^2, Dp in m^3/rad, M in kg,
        V0 in m^3.
    """
    params = (
        PhysicalParameter("leakage", leakage, "m^3/(s Pa)", "internal leakage coefficient L"),
        PhysicalParameter("friction", friction, "N s/m", "viscous friction coefficient a"),
        PhysicalParameter("bulk_modulus", bulk_modulus, "Pa", "effective bulk modulus be"),
    )
    constants = {
        "piston_area": piston_area,
        "pump_displacement": pump_displacement,
        "mass": mass,
        "volume": volume,
    }
    entries = _entries(
        {
            "A[2,2]": "1 - dt*friction/mass",
            "A[2,3]": "dt*piston_area/mass",
            "A[3,2]": "-dt*bulk_modulus*piston_area/volume",
            "A[3,3]": "1 - dt*bulk_modulus*leakage/volume",
            "B[3,1]": "dt*bulk_modulus*pump_displacement/volume",
        },
        "EHA parameter map",
    )
    return ParameterMap(params, entries, constants)


def second_order_parameter_map(f0_hz: float, zeta: float) -> ParameterMap:
    """Natural frequency (Hz) and damping ratio of the second-order system of eq (30), explicit Euler.

    ``A[2,1] = -dt (2 pi f0)^2``, ``A[2,2] = 1 - 2 dt zeta (2 pi f0)`` (B does not depend on
    them). Hypotheses: ``natural_frequency`` (f0 alone; with a nominal zeta > 0 it moves A21 and
    A22), ``damping`` (zeta alone).

    Parameters
    ----------
    f0_hz : float
        Nominal natural frequency in Hz.
    zeta : float
        Nominal damping ratio.
    """
    params = (
        PhysicalParameter("natural_frequency", f0_hz, "Hz", "undamped natural frequency f0"),
        PhysicalParameter("damping", zeta, "", "damping ratio zeta"),
    )
    entries = _entries(
        {
            "A[2,1]": "-dt*(2*pi*natural_frequency)**2",
            "A[2,2]": "1 - 2*dt*damping*(2*pi*natural_frequency)",
        },
        "second-order parameter map",
    )
    return ParameterMap(params, entries)
