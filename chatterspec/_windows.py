"""STFT tapers without importing :mod:`scipy.signal` (private).

Importing :mod:`scipy.signal` costs 0.3-0.6 s (it parses the docstrings of its array-API wrappers), which
the online monitor would pay at every start for one window. The cosine-sum windows are computed here
with the operations of ``scipy.signal.windows.general_cosine`` (periodic form: ``M + 1`` points of
``linspace(-pi, pi)``, ``w += a_k cos(k x)``, last point dropped), so they equal
``scipy.signal.get_window(name, M)`` bit for bit (``tests/test_startup.py`` checks it); any other window
name is handed to scipy.
"""

from __future__ import annotations

import numpy as np

__all__ = ["NATIVE_WINDOWS", "get_window"]

#: Windows computed here: name -> Hamming coefficient ``alpha`` of ``alpha - (1 - alpha) cos``.
NATIVE_WINDOWS: dict[str, float] = {"hamming": 0.54, "hann": 0.5}


def get_window(name: str, n: int) -> np.ndarray:
    """The periodic (DFT-even) window ``name`` of ``n`` samples, as ``scipy.signal.get_window(name, n)``.

    Parameters
    ----------
    name : str
        Window name; ``hamming`` and ``hann`` are computed here, anything else by scipy.
    n : int
        Window length in samples (>= 1).
    """
    alpha = NATIVE_WINDOWS.get(name) if isinstance(name, str) else None
    if alpha is None or int(n) != n or n < 1:
        import scipy.signal

        return np.asarray(scipy.signal.get_window(name, n), dtype=float)
    if n == 1:
        return np.ones(1)
    M = int(n) + 1
    fac = np.linspace(-np.pi, np.pi, M, dtype=np.float64)
    w = np.zeros(M, dtype=np.float64)
    for k, a in enumerate(np.asarray([alpha, 1.0 - alpha], dtype=np.float64)):
        w += a * np.cos(k * fac)
    return w[:-1]
