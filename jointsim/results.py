"""Result objects returned by solvers: data plus an honest convergence report.

Every solver returns an object carrying a :class:`Convergence`; no solver
returns bare arrays.  A run that gives up keeps what it computed and says why
in ``message``.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

#: Status codes shared by all solvers.
SUCCESS = 0
NOT_CONVERGED = 1     # iteration limit or tolerance not reached
STEP_TOO_SMALL = 2    # adaptive step shrank below its minimum
NON_FINITE = 3        # NaN or inf appeared; the run stopped before using it
INTERRUPTED = 4       # stopped by the user; what was computed is kept

STATUS_NAMES = {SUCCESS: "success", NOT_CONVERGED: "not converged",
                STEP_TOO_SMALL: "step too small", NON_FINITE: "non-finite values",
                INTERRUPTED: "interrupted"}


@dataclass(frozen=True)
class Convergence:
    """How a solver ended.

    Attributes
    ----------
    success : bool
    status : int
        One of the module's status codes (0 is success).
    message : str
        Human-readable reason, always set.
    iterations : int
        Iterations (Newton steps, periods, continuation points, as the solver
        defines and documents).
    """

    success: bool
    status: int
    message: str
    iterations: int = 0

    def as_attrs(self) -> dict:
        """Attributes for the result file."""
        return {"success": bool(self.success), "status": int(self.status),
                "status_name": STATUS_NAMES.get(self.status, "unknown"),
                "message": self.message, "iterations": int(self.iterations)}


@dataclass(frozen=True)
class PrescribedResult:
    """A prescribed-motion march of contact elements.

    Attributes
    ----------
    t : ndarray, shape (n_periods * n_samples,)
        Time of every sample [s].
    u, N, f : ndarray, shape (n_e, n_periods * n_samples)
        Tangential displacement [m], normal load [N], tangential force [N].
    n_samples : int
        Samples per period; the last ``n_samples`` form the steady loop.
    omega : float
        Base angular frequency [rad/s].
    periodicity : ndarray, shape (n_e,)
        Largest change of the force between the last two periods, relative
        to the largest slip force [-].
    convergence : Convergence
    """

    t: np.ndarray
    u: np.ndarray
    N: np.ndarray
    f: np.ndarray
    n_samples: int
    omega: float
    periodicity: np.ndarray
    convergence: Convergence = field(repr=False)

    def last_period(self):
        """``(u, f, N)`` of the last period, each of shape (n_e, n_samples)."""
        s = slice(-self.n_samples, None)
        return self.u[:, s], self.f[:, s], self.N[:, s]


def interrupt_cause(exc: BaseException) -> KeyboardInterrupt | None:
    """The :class:`KeyboardInterrupt` (SIGINT, SIGTERM) behind ``exc``, or None.

    A signal whose handler raises while a numba kernel is being called (or
    unpickled) comes out of the call as a chain of :class:`SystemError`
    ("returned a result with an exception set") caused by the interrupt; one
    that lands while a module is being imported, as an :class:`ImportError`.
    """
    seen = set()
    while exc is not None and id(exc) not in seen:
        if isinstance(exc, KeyboardInterrupt):
            return exc
        if not isinstance(exc, (SystemError, ImportError)):
            return None
        seen.add(id(exc))
        exc = exc.__cause__ or exc.__context__
    return None
