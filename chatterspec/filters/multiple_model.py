"""Multiple-model filters: SMM-SVSF ([SMM] eq 3.1-3.5, Table 1) and IMM ([IMM] eq 15-33, corrected).

Notation and corrections of ``docs/design.md`` §7.5-§7.6. Everything is batched over a
leading realization axis ``runs``; the only Python loop is over time (the recursions are sequential).

**SMM-SVSF, Table 1 reading** (default, :class:`SMMSVSF` with ``reading="table1"``): one SVSF whose
prediction is the mode-weighted prediction. Per sample, from the common posterior ``x(k|k), P(k|k)``::

    x_j = f_j(x(k|k), u(k)),  P_j = F_j P(k|k) F_j^T + Q_j,  S_j = C P_j C^T + R       (Table 1 steps 1-2)
    log p_j = log N(z(k+1) - C x_j; 0, S_j)                                           (eq 3.2-3.3, vector)
    mu_j(k+1) ∝ p_j mu_j(k)  (log domain), then mu_j >= floor and renormalize          (eq 3.1, step 3)
    x(k+1|k) = sum_j mu_j x_j,  P(k+1|k) = sum_j mu_j [P_j + (x_j - x)(x_j - x)^T]      (steps 4a-5)
    SVSF gain and update (eq 2.5-2.10) on x(k+1|k), P(k+1|k)                           (steps 6-7b)

**SMM bank reading** (``reading="bank"``): eq (3.4)-(3.5) taken literally, r independent SVSFs
(:class:`~chatterspec.filters.svsf_cov.SVSFCov`, one per mode) each weighted by its own innovation
likelihood; the output is the mu-weighted posterior.

**IMM** (:class:`IMM`), per sample with the transition matrix ``pi[i, j] = P(j at k | i at k-1)``::

    (19) c_j = sum_i pi_ij mu_i(k-1)          (18) mu_{i|j} = pi_ij mu_i(k-1) / c_j  (printed 1/mu_j)
    (20) x_0j = sum_i mu_{i|j} x_i            (21) P_0j = sum_i mu_{i|j} [P_i + (x_i - x_0j)(.)^T]
    (22)-(28) mode-matched filter j (any :class:`~chatterspec.filters.protocol.Filter`) from (x_0j, P_0j)
    (29) Lambda_j = N(e_j; 0, S_j)            (30) mu_j(k) ∝ c_j Lambda_j   (log domain)
    (31) x = sum_j mu_j x_j                   (32)-(33) P = sum_j mu_j [P_j + (x_j - x)(x_j - x)^T]

The printed (32)-(33) sum ``mu_i mu_j (x_i - x_j)(x_i - x_j)^T`` over all ``i, j``; that is exactly twice
the spread of (33) here (:func:`pairwise_spread`, tested), so it is read with a factor 1/2. For the
SVSF-type mode filters, ``e(k|k)`` of mode j is the residual of its mixed estimate ``z(k) - C x_0j``
(``docs/design.md`` I4); ``e(k-1|k-1)`` stays the value that mode stored.

Likelihoods (:func:`log_gaussian`) use the correlation-scaled ``S`` with eigenvalues floored at
1e-12 (the EHA states span about 20 decades, ``docs/design.md`` S3), so a near-singular ``S`` gives a finite,
conservative likelihood instead of NaN.

**Compiled IMM step.** When :func:`chatterspec._jit.enabled` and every mode is supported (EKF/KF,
SVSF-cov without ``vbl``, second-order SVSF, on nonlinear-EHA or linear models; see
:mod:`chatterspec.filters._imm_kernel`), :meth:`IMM.update` runs the whole recursion above in one
compiled loop over runs and samples; otherwise it drives the mode filters through the protocol,
one sample at a time. The two agree to rounding (summation order; tolerances in
``tests/test_imm_kernel.py``), and each is chunk-invariant bit for bit.
"""

from __future__ import annotations

from .bank_common import (
    BankFilter,  # noqa: F401 - old import path
    MultipleModelOutput,
    MultipleModelState,
    check_mode_probabilities,
    check_transition_matrix,
    check_weight_floor,
)
from .bank_math import EIG_FLOOR, LOG2PI, log_gaussian, normalize_log_weights, pairwise_spread  # noqa: F401 - old import path
from .imm import IMM
from .mixture import combine
from .smm_svsf import (
    DEFAULT_WEIGHT_FLOOR,  # noqa: F401 - old import path
    SMMSVSF,
)

__all__ = [
    "IMM",
    "SMMSVSF",
    "MultipleModelOutput",
    "MultipleModelState",
    "check_mode_probabilities",
    "check_transition_matrix",
    "check_weight_floor",
    "combine",
    "log_gaussian",
    "normalize_log_weights",
    "pairwise_spread",
]
