"""The offline tools' boundary for numerical failures: an input whose numbers defeat a solver is one line.

A recording with readings of 1e300 N, or rows that make a normal matrix
singular, is the user's file, not a bug: ``numpy``/``scipy`` raise
``LinAlgError`` ("SVD did not converge", "Singular matrix") deep inside an
estimator or the discrepancy workflow. :func:`numerical_failures` wraps one
tool's work on one file (``compensate``'s blocks, ``replay``, ``discrepancy``,
each file of ``bench real``) and turns that error into a :class:`NumericalError`
naming the file and, where known, the rows. Floating-point warnings (overflow
on such values) are silenced there: the result says what happened (NaN, never
converged) or the error does. Nothing else is caught.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager

import numpy as np

from hapticlab.core.errors import UserError


class NumericalError(UserError):
    """The numbers of an input defeat a solver; the message names the file (and rows when known)."""


@contextmanager
def numerical_failures(where: str, what: str = "") -> Iterator[None]:
    """Turn a ``LinAlgError`` raised inside the block into a :class:`NumericalError` about ``where``.

    ``where`` names the input ("log.csv rows 1025-2048"), ``what`` the work
    ("the rls estimator"). The original error is chained as the cause.
    """
    with np.errstate(all="ignore"):
        try:
            yield
        except np.linalg.LinAlgError as exc:
            during = f" in {what}" if what else ""
            raise NumericalError(
                f"{where}: numerical failure{during} ({exc}); check the values there "
                f"(magnitudes, repeated or degenerate rows)"
            ) from exc
