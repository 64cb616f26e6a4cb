"""The exception types for user mistakes, and the one sample-time check.

A ``UserError`` is raised for anything a user can fix: a bad config key, a malformed record, an
unstable controller design, a model used at another sample rate. Its message is one line that
names the file, the key or the column and what was expected. The CLI prints it and exits with
code 2; it never shows a traceback. It is a ``ValueError``, so code that catches the standard
exception for a bad value catches it too.
"""

import math

# Two sample times closer than this (relative) are one rate read off time stamps with jitter or
# rounding; a wrong rate is off by a factor (1e-3 s against 1e-4 s).
SAME_RATE_RTOL = 1e-3


class UserError(ValueError):
    """A mistake in user input (config, data file, option); the message is shown as is.

    One line that names the file, the key or the column and what was expected. The CLI prints
    it and exits with code 2. It is a ``ValueError``, so ``except ValueError`` catches it.

    Examples
    --------
    >>> from clm_sim import Plant, UserError
    >>> try:
    ...     Plant(mass=-1.0)
    ... except UserError as exc:
    ...     print(exc)
    plant: mass must be > 0, got -1.0
    >>> issubclass(UserError, ValueError)
    True
    """


class NotFittedError(UserError, AttributeError):
    """An identified model used before ``fit``.

    As scikit-learn's: a ``ValueError`` (through ``UserError``) and an
    ``AttributeError``, so ``hasattr``-style checks and ``except ValueError`` both work.
    Raised by ``predict``, ``feedforward`` and ``save`` of an unfitted
    ``LIPFeedforward`` or ``PGNNFeedforward``.

    Examples
    --------
    >>> import numpy as np
    >>> from clm_sim import LIPFeedforward, NotFittedError
    >>> try:
    ...     LIPFeedforward().feedforward(np.zeros(10), 1e-4)
    ... except NotFittedError as exc:
    ...     print(exc)
    LIPFeedforward is not fitted: call fit() before predict(), feedforward() or save()
    """


def check_ts(own: float | None, ts: float, owner: str) -> None:
    """Refuse to use ``owner`` (designed or fitted at ``own`` s; ``None``: unknown, anything
    goes) at sample time ``ts`` s; the ``UserError`` names both rates."""
    if own is None:
        return
    own, ts = float(own), float(ts)
    if not (math.isfinite(ts) and ts > 0):
        raise UserError(f"{owner}: sample time must be a positive number of seconds, got {ts!r}")
    if abs(ts / own - 1) > SAME_RATE_RTOL:
        raise UserError(f"{owner} has sample time {own:g} s ({1 / own:g} Hz) but is used at "
                        f"{ts:g} s ({1 / ts:g} Hz); design or fit it at that rate")
