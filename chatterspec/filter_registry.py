"""The state-estimator registry: the filter names of ``chatterspec estimate`` and of the estimator studies.

One table, read by :mod:`chatterspec.studies.estimation` (:func:`build`) and by the command line
(``chatterspec estimate --filters``, which lists :data:`FILTERS` without importing the filters).
Each entry names a builder in the filter's own module, ``builder(model, settings, source)``,
that returns the filter tuned from a :class:`~chatterspec.plants.scenarios.FilterSettings`
(``source`` names the scenario in error messages), and how the estimator figures draw it. Adding
an estimator is its module (a class of the :class:`~chatterspec.filters.protocol.Filter` protocol and
its builder) plus one :func:`register_filter` call: ``chatterspec estimate --filters``, the estimation
study, its recordings and figures then take it (``docs/design.md`` shows a whole one). The stock
filters also share the compiled correction steps of :mod:`chatterspec.filters._engine`; a new one
need not.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any

from .errors import ParameterError

__all__ = [
    "ENTRIES",
    "FILTERS",
    "FilterEntry",
    "build",
    "filter_entry",
    "parse_filters",
    "register_filter",
    "unregister_filter",
]


@dataclass(frozen=True)
class FilterEntry:
    """One registered estimator.

    Attributes
    ----------
    name : str
        The name on the command line (``--filters``).
    description : str
        One line for help texts and reports.
    builder : str or callable
        ``function(model, settings, source) -> Filter``, or ``"module:function"`` naming it (imported
        when the filter is built, so that listing the filters imports none).
    label : str
        Legend label of the figures (default: the name).
    color : str or None
        Its colour: a name of :data:`chatterspec.palette.TAB10` (None: a channel colour by position).
    style : dict
        Matplotlib line keywords of the figures (``ls``, ``lw``, ``alpha``; missing ones: ``"-"``, 1, 1).
    """

    name: str
    description: str
    builder: str | Callable[[Any, Any, str], Any]
    label: str = ""
    color: str | None = None
    style: Mapping[str, Any] = field(default_factory=dict)


_ENTRIES: dict[str, FilterEntry] = {}

#: The registered estimators by name, in the order of help texts (read-only view).
ENTRIES: Mapping[str, FilterEntry] = MappingProxyType(_ENTRIES)

#: Filter names and descriptions (what ``--filters`` accepts); kept equal to :data:`ENTRIES`.
FILTERS: dict[str, str] = {}


def register_filter(entry: FilterEntry) -> FilterEntry:
    """Add an estimator to the registry (a ``--filters`` choice from then on); returns ``entry``.

    Raises
    ------
    ParameterError
        A name already registered, or one that is not a lower-case word (it is a ``--filters`` item).
    """
    if entry.name in _ENTRIES:
        raise ParameterError(f"a filter named {entry.name!r} is already registered")
    if not entry.name or entry.name != entry.name.strip().lower() or "," in entry.name:
        raise ParameterError(f"a filter name is a lower-case word without commas; got {entry.name!r}")
    _ENTRIES[entry.name] = entry
    FILTERS[entry.name] = entry.description
    return entry


def unregister_filter(name: str) -> None:
    """Remove the estimator ``name`` (what a test that registered one does after it)."""
    _ENTRIES.pop(name, None)
    FILTERS.pop(name, None)


def filter_entry(name: str) -> FilterEntry:
    """The registry entry of ``name`` (``ParameterError`` listing the names if unknown)."""
    (name,) = parse_filters([name])
    return _ENTRIES[name]


for _entry in (
    FilterEntry(
        "kf",
        "Kalman filter (EKF on a nonlinear plant)",
        "chatterspec.filters.kalman:kf_from_settings",
        "Kalman filter",
        "blue",
        {"ls": "-", "lw": 2.6, "alpha": 0.45},
    ),
    FilterEntry(
        "ekf",
        "extended Kalman filter",
        "chatterspec.filters.kalman:ekf_from_settings",
        "EKF",
        "blue",
        {"ls": "-", "lw": 2.6, "alpha": 0.45},
    ),
    FilterEntry(
        "svsf",
        "first-order SVSF with covariance [SMM eq 2.1-2.10]",
        "chatterspec.filters.svsf_cov:from_settings",
        "1st-order SVSF",
        "orange",
        {"ls": "-", "lw": 1.3, "alpha": 0.85},
    ),
    FilterEntry(
        "svsf2",
        "dynamic second-order SVSF [DETC eq 5-24]",
        "chatterspec.filters.svsf2:from_settings",
        "dynamic 2nd-order SVSF",
        "green",
        {"ls": "--", "lw": 1.0, "alpha": 1.0},
    ),
):
    register_filter(_entry)


def parse_filters(filters: str | Any) -> tuple[str, ...]:
    """Normalize a filter list (``"kf,svsf2"`` or an iterable) and reject unknown or repeated names.

    Parameters
    ----------
    filters : str or iterable of str
        Comma-separated names or a sequence of names from :data:`FILTERS`.

    Returns
    -------
    tuple of str

    Raises
    ------
    ParameterError
        An empty list, an unknown name or a repeated name.
    """
    names = [s.strip().lower() for s in (filters.split(",") if isinstance(filters, str) else filters)]
    names = [s for s in names if s]
    if not names:
        raise ParameterError(f"no filter given; choose from {', '.join(FILTERS)}")
    bad = [s for s in names if s not in FILTERS]
    if bad:
        raise ParameterError(f"unknown filter(s) {', '.join(bad)}; choose from {', '.join(FILTERS)}")
    if len(set(names)) != len(names):
        raise ParameterError(f"each filter may be named once; got {','.join(names)}")
    return tuple(names)


def build(name: str, model: object, settings: object, source: str) -> Any:
    """The registered filter ``name`` on ``model`` with the tuning of ``settings``.

    Parameters
    ----------
    name : str
        One of :data:`FILTERS`.
    model : model object
        The filter's model (Q and R of the settings already in it).
    settings : FilterSettings
        Tuning (psi, gamma, cutoff_lambda, mapping, ...).
    source : str
        Name of the scenario, for error messages.

    Returns
    -------
    Filter

    Raises
    ------
    ParameterError
        Unknown name, or a setting the filter needs but ``settings`` lacks.
    """
    entry = filter_entry(name)
    builder = entry.builder
    if isinstance(builder, str):
        module, function = builder.split(":")
        builder = getattr(importlib.import_module(module), function)
    return builder(model, settings, source)
