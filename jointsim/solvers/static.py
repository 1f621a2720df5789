"""Nonlinear static equilibrium with contact (bolt preload, quasi-static loading).

Solves ``R(x) = K x + Tt^T f_t(x) - Tn^T N(x) - f = 0`` for a structure with
a :class:`~jointsim.model.ContactSet` (sign conventions in
:mod:`jointsim.model`), by Newton's method with a backtracking line search and
load stepping: the load goes from ``f_start`` to ``f`` in increments; a
failed increment is halved and retried, and a solve that gives up returns the
last converged state with the reason.

Normal contact (``normal``, a :class:`~jointsim.contact.normal.NormalLaw`;
default the contact set's own):

* a coupled law (unilateral or bilateral penalty): ``N(g)``, ``g = gap0 + Tn x``,
  with the closed side's derivative at ``g = 0``;
* :class:`~jointsim.contact.normal.GivenNormal`: ``N = N0`` is the slip limit
  only; the normal force is the linear spring already in ``K``
  (:func:`jointsim.model.with_fixed_normal_springs`), so the ``Tn^T N`` term
  is left out.

Tangential contact (``tangential``):

* ``"stuck"``: a Jenkins element that never slips, ``f_t = kt A (u_t - w)``
  while in contact (``g <= 0``; ``N0 > 0`` for a fixed normal load) and 0
  while separated (``w``: the anchors, from ``state``,
  default 0);
* ``"linear"``: the spring ``kt A (u_t - w)`` whatever ``N``;
* ``"frictionless"``: ``f_t = 0``;
* ``"law"``: the contact set's law marched by one step from ``state`` (one
  quasi-static load increment, friction history included); the returned
  ``state`` is the law state at the solution.

The Jacobian is exact (piecewise): ``K + Tt^T D_u Tt + Tt^T D_N D_g Tn -
Tn^T D_g Tn`` with ``D_u = df_t/du_t``, ``D_N = df_t/dN``, ``D_g = dN/dg``.
At a converged point it is the tangent stiffness of the state.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from ..loads import static_load
from ..results import NON_FINITE, NOT_CONVERGED, STEP_TOO_SMALL, SUCCESS, Convergence
from .contact_map import ContactMap, empty_eval
from .newton import NewtonOptions, newton

log = logging.getLogger(__name__)

TANGENTIAL_MODES = ("stuck", "linear", "frictionless", "law")


@dataclass(frozen=True)
class StaticResult:
    """A static equilibrium.

    Attributes
    ----------
    x : ndarray, shape (n_dof,)
        Displacements [m].
    N : ndarray, shape (n_e,)
        Normal loads [N].
    gap : ndarray, shape (n_e,)
        Normal gaps ``gap0 + Tn x`` [m].
    u_t : ndarray, shape (n_e,)
        Tangential slips ``Tt x`` [m].
    f_t : ndarray, shape (n_e,)
        Tangential forces [N].
    state : ndarray
        Tangential state at the solution (anchors for ``stuck``/``linear``,
        the law's state for ``law``).
    K_t : scipy.sparse.csr_matrix, shape (n_dof, n_dof)
        Tangent stiffness at ``x`` [N/m].  For ``tangential = "law"`` it is
        the consistent tangent of the last load increment (sliders that
        slipped in it have zero stiffness: the tangent for continued
        loading); :func:`tangent_stiffness` with the returned ``state``
        gives the tangent for a reversal (everything sticks).
    load_factor : float
        Fraction of the load increment ``f - f_start`` reached (1 on success).
    residual : float
        Final ``||R|| / scale`` [-].
    convergence : Convergence
        ``iterations`` counts Newton iterations over all increments.
    """

    x: np.ndarray
    N: np.ndarray
    gap: np.ndarray
    u_t: np.ndarray
    f_t: np.ndarray
    state: np.ndarray
    K_t: sp.csr_matrix
    load_factor: float
    residual: float
    convergence: Convergence = field(repr=False)


#: Models up to this many DOFs are solved with dense matrices: reduced models
#: are small and dense algebra has no per-call sparse bookkeeping (a sparse
#: Jacobian assembly cost ~4 ms even for one DOF).
DENSE_MAX_DOF = 2000
#: ... and so are larger ones whose stiffness has at least this share of its entries:
#: a reduced model's stiffness is dense at any size (round 42: the default scene at 504
#: Gauss points, 2,060 DOFs, solved its preload through a sparse LU of a dense matrix).
DENSE_MIN_FILL = 0.25


class _Problem:
    """Residual and Jacobian of the static equations (one load increment)."""

    def __init__(self, K, contacts, normal, tangential, state):
        n = K.shape[0]
        self.dense = n <= DENSE_MAX_DOF or (
            K.nnz if sp.issparse(K) else np.count_nonzero(K)) >= DENSE_MIN_FILL * n * n
        if self.dense:
            self.K = K.toarray() if sp.issparse(K) else np.asarray(K, dtype=float)
        else:
            self.K = sp.csr_matrix(K)
        # the contact matrices stay sparse: each element's row has a few entries, and
        # the contact Jacobian ``Tt^T diag(.) Tt`` formed dense cost 131 ms per
        # evaluation at 480 Gauss points (1,964 DOFs), 4.5 ms sparse (0.6 ms against
        # 1.3 ms at 96; round 42)
        self.Tt = sp.csr_matrix(contacts.Tt)
        self.Tn = sp.csr_matrix(contacts.Tn)
        self.TtT = self.Tt.T.tocsr()
        self.TnT = self.Tn.T.tocsr()
        self.c = contacts
        self.normal = normal
        self.tangential = tangential
        self.state = state
        ne = contacts.n_elements
        self.kt = contacts.law.kt if tangential in ("stuck", "linear") else np.zeros(ne)

    def evaluate(self, x, f, jacobian=True):
        c = self.c
        g = c.gap0 + self.Tn @ x
        # the boundary g = 0 belongs to the closed side (a generalised
        # Jacobian): starting from touching surfaces, the first Newton step
        # sees the contact stiffness, so bodies held only by the contact are
        # not singular
        if self.normal.coupled:
            N, dNdg = self.normal.load(g, closed_at_zero=True)
            closed = self.normal.closed(g)
        else:
            N = np.asarray(c.N0, dtype=float).copy()
            closed = N > 0.0
            dNdg = np.zeros_like(N)
        u = self.Tt @ x
        new_state = self.state
        if self.tangential in ("stuck", "linear"):
            on = closed if self.tangential == "stuck" else np.ones(N.shape, bool)
            dfdu = np.where(on, self.kt, 0.0)
            ft = dfdu * (u - self.state)
            dfdN = np.zeros_like(ft)
        elif self.tangential == "frictionless":
            ft = np.zeros_like(u)
            dfdu = np.zeros_like(u)
            dfdN = np.zeros_like(u)
        else:
            ft, dfdu, dfdN, new_state = c.law.march(u[:, None], N[:, None], self.state)
            ft, dfdu, dfdN = ft[:, 0], dfdu[:, 0], dfdN[:, 0]
        fc_t = self.TtT @ ft
        fc_n = self.TnT @ N
        fint = self.K @ x + fc_t
        if self.normal.coupled:  # a fixed normal load is a linear spring in K
            fint = fint - fc_n
        R = fint - f
        scale = max(np.linalg.norm(f), np.linalg.norm(fc_n), np.linalg.norm(fc_t), 1e-300)
        out = dict(R=R, scale=scale, N=N, g=g, u=u, ft=ft, state=new_state)
        if jacobian:
            Tt, Tn, TtT, TnT = self.Tt, self.Tn, self.TtT, self.TnT
            Jc = (TtT @ sp.diags(dfdu) @ Tt + TtT @ sp.diags(dfdN * dNdg) @ Tn
                  - TnT @ sp.diags(dNdg) @ Tn)
            if self.dense:
                J = Jc.toarray()
                J += self.K
            else:
                J = sp.csr_matrix(self.K + Jc)
            out["J"] = J
        return out


def _default_modes(contacts, normal, tangential):
    law = contacts.law
    if normal is None:
        normal = contacts.normal
    if tangential is None:
        tangential = "law"
    if tangential == "law" and not law.has_force:
        tangential = "frictionless"
    elif tangential == "law" and not law.can_slip:
        tangential = "linear"
    if tangential not in TANGENTIAL_MODES:
        raise ValueError(f"tangential must be one of {TANGENTIAL_MODES}, got {tangential!r}")
    return normal, tangential


def _initial_state(contacts, tangential, state):
    if state is not None:
        return np.array(state, dtype=float, copy=True)
    ne = contacts.n_elements
    if tangential == "law":
        return contacts.law.rest_state(contacts.N0)
    return np.zeros(ne)


def stuck_mode(contacts) -> str:
    """The tangential mode of a stuck interface for the scene's law.

    ``"linear"`` for the linear (``stuck``) law, ``"frictionless"`` without
    friction, else ``"stuck"`` (sticks where the element is in contact, like
    the friction laws at small amplitude).
    """
    law = contacts.law
    if not law.has_force:
        return "frictionless"
    return "stuck" if law.can_slip else "linear"


def tangent_stiffness(K, contacts, x, *, tangential=None, normal=None, state=None):
    """Tangent stiffness ``dR/dx`` at ``x``.

    Parameters
    ----------
    K : sparse matrix, shape (n_dof, n_dof)
    contacts : jointsim.model.ContactSet
    x : ndarray, shape (n_dof,)
    tangential : str, optional
        Mode as in :func:`solve_static`; defaults to the stuck interface
        (:func:`stuck_mode`).
    normal : jointsim.contact.normal.NormalLaw, optional
        Normal law (default: the contact set's).
    state : ndarray, optional

    Returns
    -------
    scipy.sparse.csr_matrix, shape (n_dof, n_dof) [N/m]
    """
    if tangential is None:
        tangential = stuck_mode(contacts)
    normal, tangential = _default_modes(contacts, normal, tangential)
    prob = _Problem(K, contacts, normal, tangential,
                    _initial_state(contacts, tangential, state))
    return sp.csr_matrix(prob.evaluate(np.asarray(x, dtype=float), np.zeros(K.shape[0]))["J"])


def residual(K, f, contacts, x, *, tangential=None, normal=None, state=None):
    """Residual ``R(x)`` of the static equations [N], shape (n_dof,)."""
    normal, tangential = _default_modes(contacts, normal, tangential)
    prob = _Problem(K, contacts, normal, tangential,
                    _initial_state(contacts, tangential, state))
    return prob.evaluate(np.asarray(x, dtype=float), np.asarray(f, dtype=float),
                         jacobian=False)["R"]


def _factor_solve(J, b):
    if not sp.issparse(J):
        return np.linalg.solve(J, b)
    return spla.splu(sp.csc_matrix(J)).solve(b)


def _newton(prob, x, f, tol, max_iter):
    """Newton with an Armijo line search at load ``f``: a :class:`NewtonResult` whose
    ``extra`` is the evaluation at ``x``; converged when ``||R|| <= tol * scale``."""
    def fun(x_):
        ev = prob.evaluate(x_, f)
        return ev["R"], ev["J"], ev

    return newton(fun, x,
                  NewtonOptions(tol, max_iter, check_start=True, line_search="armijo",
                                max_tries=7, finite_step=True),
                  solve=_factor_solve, measure=lambda R, _ev: np.linalg.norm(R),
                  threshold=lambda _x, ev: tol * ev["scale"])


def solve_static(K, f, contacts, *, tangential=None, normal=None, state=None,
                 x_start=None, f_start=None, tol: float = 1e-10, max_iter: int = 30,
                 n_increments: int = 1, min_increment: float = 1e-4) -> StaticResult:
    """Static equilibrium of a structure with contact.

    Parameters
    ----------
    K : sparse matrix, shape (n_dof, n_dof)
        Linear stiffness [N/m]; nonsingular on its own is not required.
    f : ndarray, shape (n_dof,)
        Applied load [N].
    contacts : jointsim.model.ContactSet
    tangential : str, optional
        ``stuck``, ``linear``, ``frictionless`` or ``law`` (default ``law``;
        see the module docstring).
    normal : jointsim.contact.normal.NormalLaw, optional
        Normal law (default: the contact set's; see the module docstring).
    state : ndarray, optional
        Tangential state at the start (anchors of shape (n_e,) for
        ``stuck``/``linear``; the law's state for ``law``; default rest).
    x_start : ndarray, shape (n_dof,), optional
        Converged state at ``f_start`` (default 0).
    f_start : ndarray, shape (n_dof,), optional
        Load at ``x_start`` (default 0).
    tol : float
        Relative residual tolerance ``||R|| <= tol * scale`` with ``scale``
        the largest of ``||f||``, ``||Tn^T N||``, ``||Tt^T f_t||``.
    max_iter : int
        Newton iterations per increment.
    n_increments : int
        Initial number of load increments (grows after successes, halves
        after failures).
    min_increment : float
        Smallest load-factor increment before giving up.

    Returns
    -------
    StaticResult
    """
    normal, tangential = _default_modes(contacts, normal, tangential)
    n = K.shape[0]
    f = np.asarray(f, dtype=float)
    x = np.zeros(n) if x_start is None else np.array(x_start, dtype=float)
    f0 = np.zeros(n) if f_start is None else np.asarray(f_start, dtype=float)
    st = _initial_state(contacts, tangential, state)
    lam, dlam = 0.0, 1.0 / max(1, n_increments)
    total_it, message, status = 0, "", SUCCESS
    ev = _Problem(K, contacts, normal, tangential, st).evaluate(x, f0)
    while lam < 1.0:
        step = min(dlam, 1.0 - lam)
        prob = _Problem(K, contacts, normal, tangential, st)
        f_l = f0 + (lam + step) * (f - f0)
        nr = _newton(prob, x, f_l, tol, max_iter)
        total_it += nr.iterations
        msg = nr.message
        if nr.success:
            x, ev = nr.x, nr.extra
            lam = 1.0 if step >= 1.0 - lam else lam + step
            st = ev["state"]
            dlam = min(2.0 * step, 1.0)
            continue
        if nr.status == NON_FINITE:
            status, message = NON_FINITE, msg
        dlam = 0.5 * step
        log.debug("static: increment %.3g failed (%s); retrying with %.3g", step, msg, dlam)
        if dlam < min_increment:
            status = status if status == NON_FINITE else STEP_TOO_SMALL
            message = (f"gave up at load factor {lam:.4g}: increment below {min_increment:g}"
                       f" ({msg})")
            break
    if lam >= 1.0:
        message = (f"converged in {total_it} Newton iterations "
                   f"(residual {np.linalg.norm(ev['R']) / ev['scale']:.1e})")
    success = lam >= 1.0
    if not success and status == SUCCESS:
        status = NOT_CONVERGED
    conv = Convergence(success, status if not success else SUCCESS, message, total_it)
    res = np.linalg.norm(ev["R"]) / ev["scale"]
    if not success:
        log.warning("static solve: %s", message)
    return StaticResult(x=x, N=ev["N"], gap=ev["g"], u_t=ev["u"], f_t=ev["ft"], state=st,
                        K_t=sp.csr_matrix(ev["J"]), load_factor=lam, residual=float(res), convergence=conv)



# --------------------------------------------------------------------------
# The static state of a model and the linearisation of its stuck joint
# --------------------------------------------------------------------------
@dataclass(frozen=True)
class StuckLinearisation:
    """The static state ``x0`` of a model and the stuck tangent stiffness there.

    This is the one definition of "the linear joint" that every solver uses:
    the linear modes, the EPMC reference mode and its low-amplitude limit,
    the harmonic-balance start (its harmonic-0 part) and QSMA's ``K0``.

    Attributes
    ----------
    x0 : ndarray, shape (n_dof,)
        Static displacement [m]: the equilibrium of
        ``K x + f_c(x) = f0`` with the tangential contacts stuck.
    K : scipy.sparse.csr_matrix, shape (n_dof, n_dof)
        Tangent stiffness at ``x0`` with the interface stuck [N/m]: ``K``,
        ``kt A`` of every element in contact (closed), and ``kn A`` of every
        closed element when the normal load is coupled (with a fixed normal
        load the normal springs are already part of ``K``).
    f0 : ndarray, shape (n_dof,)
        Static load [N]: ``f_static`` plus the constant parts of the loads.
    N : ndarray, shape (n_e,)
        Normal load of each element at ``x0`` [N] (``N0`` for a fixed normal load).
    gap : ndarray, shape (n_e,)
        Normal gap at ``x0`` [m] (``gap0 + Tn x0``).
    closed : ndarray of bool, shape (n_e,)
        Elements in contact at ``x0`` (these carry the stuck springs).
    source : str
        ``"model"`` (``x0`` solved by the model builder, e.g. the bolt
        preload) or ``"solved"`` (solved here).
    convergence : Convergence
    """

    x0: np.ndarray
    K: sp.csr_matrix
    f0: np.ndarray
    N: np.ndarray
    gap: np.ndarray
    closed: np.ndarray
    source: str
    convergence: Convergence = field(repr=False)


def stuck_linearisation(model, *, tol: float = 1e-10) -> StuckLinearisation:
    """The static state of a structural model and its stuck linearisation.

    ``x0`` is ``model.preload.x0`` when the builder solved it (FE and ROM
    models: the bolt preload, which is the equilibrium of the model's own
    ``K`` and ``f_static``); otherwise it is solved here by
    :func:`solve_static` under the static load ``f0`` (``f_static`` plus the
    constant parts of the loads), with the tangential contacts stuck and the
    scene's normal contact.  The tangent at ``x0`` comes from
    :func:`tangent_stiffness` with the stuck interface (:func:`stuck_mode`).

    A :class:`~jointsim.model.StructuralModel` computes it once, when it is
    constructed, and keeps it as ``model.linearisation``: solvers read that.

    Parameters
    ----------
    model : jointsim.model.StructuralModel
    tol : float
        Residual tolerance of the static solve (when one is needed).

    Returns
    -------
    StuckLinearisation

    Raises
    ------
    RuntimeError
        When the static state cannot be solved (the message says why).
    """
    c = model.contacts
    f0 = static_load(model)
    normal, tangential = _default_modes(c, None, stuck_mode(c))
    given = None if model.preload is None else model.preload.x0
    x_start = np.zeros(model.n_dof) if given is None else np.asarray(given, dtype=float)
    r = residual(model.K, f0, c, x_start, tangential=tangential, normal=normal)
    scale = max(np.linalg.norm(f0), np.linalg.norm(model.K @ x_start), 1e-300)
    if np.linalg.norm(r) <= max(tol, 1e-8) * scale:
        x0, source = x_start, ("model" if given is not None else "solved")
        what = "from the model builder" if given is not None else "x = 0"
        conv = Convergence(True, SUCCESS, f"static state {what} (residual "
                                          f"{np.linalg.norm(r) / scale:.1e})", 0)
    else:
        # x_start is the equilibrium of f0 + r: step the load from there to f0
        res = solve_static(model.K, f0, c, tangential=tangential, normal=normal, tol=tol,
                           x_start=x_start, f_start=f0 + r)
        if not res.convergence.success:
            raise RuntimeError(f"static state (stuck joint under the static load): "
                               f"{res.convergence.message}")
        x0, source, conv = res.x, "solved", res.convergence
    prob = _Problem(model.K, c, normal, tangential, _initial_state(c, tangential, None))
    ev = prob.evaluate(x0, f0)
    if normal == "fixed":
        closed = np.asarray(c.N0, dtype=float) > 0.0
    else:
        closed = ev["g"] <= 0.0
    lin = StuckLinearisation(x0=x0, K=sp.csr_matrix(ev["J"]), f0=f0, N=np.asarray(ev["N"]),
                             gap=np.asarray(ev["g"]), closed=closed, source=source,
                             convergence=conv)
    log.debug("stuck linearisation: %d/%d elements closed at x0 (%s)", int(closed.sum()),
              c.n_elements, conv.message)
    return lin


@dataclass(frozen=True)
class StartState:
    """The static state a march starts from, with the contact laws' state there.

    Attributes
    ----------
    x : ndarray, shape (n_dof,)
        Static displacement [m].
    contact : ContactEval
        Contact forces at ``x``; ``contact.state`` is the law state to start from.
    iterations : int
        Newton iterations of the static solves.
    source : str
        Where ``x`` comes from (the stuck linearisation's ``source``, or
        ``"frictionless"``).
    """

    x: np.ndarray
    contact: object
    iterations: int
    source: str


def static_start(model, frictionless: bool = False, tol: float = 1e-10) -> StartState:
    """The static state under the constant loads, and the laws' state there.

    The state is the one every solver starts from,
    :func:`jointsim.solvers.static.stuck_linearisation` (the model builder's
    preload state when it has one, else solved with the joint stuck), with
    the sliders at rest: anchors at zero slip, so that a stuck slider carries
    ``kt A u_t``.  Where that force exceeds the slip limit, one
    :func:`~jointsim.solvers.static.solve_static` step with the law itself
    (``tangential = "law"``) lets the slider slip to equilibrium.

    With ``frictionless`` (``model.preload_tangential = "frictionless"``) the
    static state carries no tangential force (``solve_static`` with
    ``tangential = "frictionless"``), and the sliders rest, unloaded, at the
    slip it leaves.

    Parameters
    ----------
    model : jointsim.model.StructuralModel
    frictionless : bool
    tol : float
        Residual tolerance of the static solves.

    Returns
    -------
    StartState

    Raises
    ------
    RuntimeError
        When a static solve fails (the message says why).
    """
    c = model.contacts
    cmap = ContactMap(c)
    f0 = static_load(model)
    if frictionless and cmap.active:
        x_start = None if model.preload is None else model.preload.x0
        res = solve_static(model.K, f0, c, tangential="frictionless", tol=tol,
                           x_start=x_start, f_start=None if x_start is None else f0)
        if not res.convergence.success:
            raise RuntimeError(f"the static (preload) state, frictionless: "
                               f"{res.convergence.message}")
        state = cmap.state_at(res.u_t, res.N)
        ev = cmap.evaluate(cmap.B @ res.x, state)
        return StartState(res.x, ev, res.convergence.iterations, "frictionless")
    lin = model.linearisation
    if not cmap.active:
        return StartState(lin.x0, empty_eval(c.law.rest_state(np.zeros(0))),
                          lin.convergence.iterations, lin.source)
    rest = c.law.rest_state(lin.N)
    if not c.law.can_slip:   # linear or no friction: no history to solve for
        return StartState(lin.x0, cmap.evaluate(cmap.B @ lin.x0, rest),
                          lin.convergence.iterations, lin.source)
    res = solve_static(model.K, f0, c, tangential="law", state=rest, tol=tol,
                       x_start=lin.x0, f_start=f0)
    if not res.convergence.success:
        raise RuntimeError(f"the static state with the contact law: {res.convergence.message}")
    ev = cmap.evaluate(cmap.B @ res.x, res.state)
    return StartState(res.x, ev, lin.convergence.iterations + res.convergence.iterations,
                      lin.source)
