"""The state-estimator registry: the filter names of ``chatterspec estimate`` and of the estimator studies.

One table, read by :mod:`chatterspec.studies.estimation` (:func:`build`) and by the command line
(``chatterspec estimate --filters``, which lists :data:`FILTERS` without importing the filters).
Each entry names a builder in the filter's own module, ``builder(model, settings, source)``,
that returns the filter tuned from a :class:`~chatterspec.plants.filter_settings.FilterSettings`
(``source`` names the scenario in error messages). Adding an estimator is its module (the class,
its correction step for :mod:`chatterspec.filters._engine`, its builder) plus one entry here.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass
from typing import Any

from .errors import ParameterError

__all__ = ["ENTRIES", "FILTERS", "FilterEntry", "build", "parse_filters"]


@dataclass(frozen=True)
class FilterEntry:
    """One registered estimator.

    Attributes
    ----------
    name : str
        The name on the command line (``--filters``).
    description : str
        One line for help texts and reports.
    builder : str
        ``"module:function"`` of ``function(model, settings, source) -> Filter``.
    """

    name: str
    description: str
    builder: str


#: The registered estimators, in the order of help texts.
ENTRIES: tuple[FilterEntry, ...] = (
    FilterEntry(
        "kf", "Kalman filter (EKF on a nonlinear plant)", "chatterspec.filters.kalman:kf_from_settings"
    ),
    FilterEntry("ekf", "extended Kalman filter", "chatterspec.filters.kalman:ekf_from_settings"),
    FilterEntry(
        "svsf",
        "first-order SVSF with covariance [SMM eq 2.1-2.10]",
        "chatterspec.filters.svsf_cov:from_settings",
    ),
    FilterEntry(
        "svsf2", "dynamic second-order SVSF [DETC eq 5-24]", "chatterspec.filters.svsf2:from_settings"
    ),
)

#: Filter names and descriptions (what ``--filters`` accepts).
FILTERS: dict[str, str] = {e.name: e.description for e in ENTRIES}


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
    (name,) = parse_filters([name])
    entry = next(e for e in ENTRIES if e.name == name)
    module, function = entry.builder.split(":")
    return getattr(importlib.import_module(module), function)(model, settings, source)
