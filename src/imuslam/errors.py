"""The errors imuslam raises, and the exit codes the command line gives them.

- :class:`InputError` (exit 2): bad input; the message names the file (line, field) or option and what
  was expected. A caller's misuse of the library (a wrong shape, an unknown method name) is a
  ValueError or TypeError instead, never exit 2.
- :class:`EstimatorError` (exit 3), e.g. :class:`FilterDivergence`: the input was read but an estimator
  failed on it; the message names the sample, scan or frame.
- :class:`HardwareError` (exit 4): a device did not answer as its protocol says.
"""

from __future__ import annotations


class ImuslamError(Exception):
    """Root of every error imuslam raises on purpose."""

    exit_code = 1


class InputError(ImuslamError, ValueError):
    """Bad input: the message names the file (and line or field) and what was expected."""

    exit_code = 2


class EstimatorError(ImuslamError):
    """An estimator failed on valid input; the message names the sample, scan or frame."""

    exit_code = 3


class FilterDivergence(EstimatorError):
    """A filter's state or covariance became invalid; the message names the sample and time."""


class HardwareError(ImuslamError):
    """A device (serial IMU, gimbal, LiDAR) is missing or does not follow its protocol."""

    exit_code = 4


def raise_if_interrupted(exc: BaseException) -> None:
    """Re-raise the KeyboardInterrupt (SIGINT, or SIGTERM as the command line maps it) behind ``exc``.

    A signal that arrives while a compiled kernel runs surfaces as another error (a SystemError whose
    context is the interrupt): code that records a failure and goes on (a study's cell) calls this first,
    so an interrupt stops the run instead of being recorded as one more failure."""
    e: BaseException | None = exc
    for _ in range(10):
        if e is None:
            return
        if isinstance(e, KeyboardInterrupt):
            raise e
        e = e.__cause__ or e.__context__
