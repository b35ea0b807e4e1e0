"""Rerun recording of an estimator comparison: truth, estimates and innovations per filter.

Entity layout (one ``time`` timeline, durations in integer nanoseconds, rounded once)::

    /states/<state>/truth                 true state x_i(k)
    /states/<state>/<filter>              estimate x_i(k|k) of each filter
    /errors/<state>/<filter>              estimation error x_i - x_i(k|k)
    /measurements/<output>                z_j(k)
    /innovations/<output>/<filter>        e_j(k|k-1) = z_j(k) - C x(k|k-1)
    /info                                 a text log line naming the scenario, run and filters

Everything time-indexed goes through ``RecordingStream.send_columns`` (bulk, millions of samples
per second); ``rerun`` is imported only when a recording is written.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from ..errors import ParameterError

__all__ = ["record_estimates"]


def _ns(seconds: np.ndarray) -> np.ndarray:
    """Seconds -> integer nanoseconds (one rounding rule for every column)."""
    return np.round(np.asarray(seconds, dtype=float) * 1e9).astype(np.int64).astype("timedelta64[ns]")


def record_estimates(records: Any, path: str | Path, *, run: int = 0) -> Path:
    """Write one realization of :class:`~chatterspec.studies.estimation.EstimateRecords` to an ``.rrd`` file.

    Parameters
    ----------
    records : EstimateRecords
        Truth, measurements and filter outputs
        (from :func:`~chatterspec.studies.estimation.estimate_records`).
    path : str or Path
        Output file, ending in ``.rrd`` (parent folders are created).
    run : int
        Which realization of ``records`` to log (index into its run axis).

    Returns
    -------
    Path
        The file written (closed, with its footer).

    Raises
    ------
    ParameterError
        A path not ending in ``.rrd`` or a run index out of range.
    """
    path = Path(path)
    if path.suffix != ".rrd":
        raise ParameterError(f"recording path must end in .rrd; got {str(path)!r}")
    runs = records.x.shape[0]
    if not 0 <= run < runs:
        raise ParameterError(f"run must be in [0, {runs}); got {run}")
    import rerun as rr

    sc = records.scenario
    model = sc.nominal
    states = tuple(model.state_names)
    outputs = tuple(model.output_names)
    path.parent.mkdir(parents=True, exist_ok=True)
    rec = rr.RecordingStream("chatterspec", recording_id=f"estimate-{sc.name}-{records.first_run + run}")
    try:
        rec.save(str(path))
    except RuntimeError as exc:  # rerun reports file errors (e.g. disk full) as RuntimeError
        from .viewer import file_error

        err = file_error(exc, path)
        if err is None:
            raise ParameterError(f"cannot write the recording {str(path)!r}: {exc}") from None
        raise err from None
    try:
        rec.send_recording_name(f"estimate {sc.name} run {records.first_run + run}")
        t_all = rr.TimeColumn("time", duration=_ns(records.t))
        t_post = rr.TimeColumn("time", duration=_ns(records.t[1:]))
        names = list(records.outputs)
        rec.log(
            "/info",
            rr.TextLog(
                f"scenario {sc.name}, realization {records.first_run + run}, filters {', '.join(names)}",
                level="INFO",
            ),
            static=True,
        )
        x = records.x[run]
        for i, s in enumerate(states):
            rec.send_columns(
                f"/states/{s}/truth", indexes=[t_all], columns=rr.Scalars.columns(scalars=x[:, i])
            )
        for j, o in enumerate(outputs):
            rec.send_columns(
                f"/measurements/{o}",
                indexes=[t_all],
                columns=rr.Scalars.columns(scalars=records.z[run, :, j]),
            )
        for name in names:
            out = records.outputs[name]
            est = out.x_post[run]
            err = x[1:] - est
            for i, s in enumerate(states):
                rec.send_columns(
                    f"/states/{s}/{name}", indexes=[t_post], columns=rr.Scalars.columns(scalars=est[:, i])
                )
                rec.send_columns(
                    f"/errors/{s}/{name}", indexes=[t_post], columns=rr.Scalars.columns(scalars=err[:, i])
                )
            if out.innovation is not None:
                for j, o in enumerate(outputs):
                    rec.send_columns(
                        f"/innovations/{o}/{name}",
                        indexes=[t_post],
                        columns=rr.Scalars.columns(scalars=out.innovation[run, :, j]),
                    )
        rec.flush()
    finally:
        rec.disconnect()
    return path
