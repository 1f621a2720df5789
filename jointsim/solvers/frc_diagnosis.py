"""Why an FRC branch failed: the undamped resonances of the linearised joint.

With no viscous damping (``model.C`` zero on a mode) the stuck or the slipping
joint has resonances where the response is unbounded unless friction can
dissipate the force's work.  :func:`undamped_resonances` finds them from the
linearised stuck and slipping systems and decides, by the work the force does
per cycle against the most the sliders can dissipate (Den Hartog's balance),
whether friction bounds the response; :func:`diagnose_failure` names the one
nearest a failed branch's last frequency, so the message says what is physics
and what the user can change (:func:`explain_branch_failure`).  Used by
:mod:`jointsim.analyses.hbm`.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from ..results import Convergence

log = logging.getLogger(__name__)


@dataclass
class UndampedResonance:
    """A resonance of a linearised joint system without viscous damping.

    Attributes
    ----------
    joint : str
        ``"stuck"`` (every closed contact stuck) or ``"slipping"`` (the
        tangential springs of the closed contacts removed: the joint in
        macroslip, normal springs kept).
    omega : float
        Undamped natural frequency [rad/s].
    mode : int
        0-based index among that system's modes.
    force_work : float
        ``pi |phi^T F_1|``: work per cycle of the fundamental force on the
        mode, per unit modal amplitude [N m / m].
    friction_work : float
        ``4 sum_e mu N_e |Tt phi|_e``: the most the sliders dissipate per cycle
        in macroslip, per unit modal amplitude (static normal loads); 0 for a
        contact that cannot slip.  With a coupled normal load the static
        ``N_e`` is used (an estimate).
    unbounded : bool
        The response grows without bound there: a stuck mode whose contacts
        cannot slip (or do not move in it), or a slipping mode whose friction
        cannot dissipate the force's work (``force_work > friction_work``,
        the Den Hartog criterion of an undamped oscillator with Coulomb
        friction).
    """

    joint: str
    omega: float
    mode: int
    force_work: float
    friction_work: float
    unbounded: bool

    def describe(self) -> str:
        """One sentence naming the resonance, why it is or is not bounded, and what to change."""
        where = (f"the {self.joint} joint's resonance at omega = {self.omega:.6g} "
                 f"(mode {self.mode + 1}) has no viscous damping (model.C)")
        if self.unbounded:
            if self.friction_work == 0.0:
                why = "and its contacts cannot slip there, so nothing limits the response"
            else:
                why = (f"and friction cannot dissipate the force's work (per cycle and unit "
                       f"modal amplitude {self.force_work:.3g} > {self.friction_work:.3g}, "
                       f"the most the sliders dissipate)")
            return (f"{where} {why}: the response is unbounded there (physics, not a "
                    f"numerical failure); add damping to model.C, or lower the force below "
                    f"{self.friction_work / max(self.force_work, 1e-300):.3g} times its value"
                    if self.friction_work > 0.0 else
                    f"{where} {why}: the response is unbounded there (physics, not a "
                    f"numerical failure); add damping to model.C")
        if self.joint == "stuck":
            return (f"{where}; the response grows there until the contacts slip, and then "
                    f"friction alone limits it, so the peak is very sharp; add damping to "
                    f"model.C or lower analysis.hbm.step_min to resolve it")
        return (f"{where}; friction alone limits the response (force work per cycle "
                f"{self.force_work:.3g} < {self.friction_work:.3g} dissipated in macroslip), "
                f"so the peak is bounded but very sharp; add damping to model.C or "
                f"lower analysis.hbm.step_min to resolve it")


#: :func:`explain_branch_failure` looks for undamped resonances (two dense
#: eigen-decompositions of the structure) up to this many DOFs; above, it says so in the
#: log (round 43; it was silent).
UNDAMPED_MAX_DOF = 2000


def undamped_resonances(model, basis, F, omega_lo: float, omega_hi: float, zeta_tol: float = 1e-9,
                        max_dof: int = UNDAMPED_MAX_DOF) -> list:
    """Resonances in ``[omega_lo, omega_hi]`` of the linearised stuck and slipping joint
    systems that carry no viscous damping.

    The stuck system is ``model.linearisation.K``; the slipping one removes the
    stuck tangential springs ``Tt^T diag(kt) Tt`` of the closed elements.  A
    mode is undamped when its modal damping ratio ``phi^T C phi / (2 omega)``
    (mass-normalised ``phi``) is below ``zeta_tol``.  Whether the response is
    unbounded there is decided per mode (:class:`UndampedResonance`).

    Parameters
    ----------
    model : jointsim.model.StructuralModel
    basis : jointsim.harmonics.HarmonicBasis
        The harmonics of ``F``'s rows.
    F : ndarray, shape (n_coeff, n_dof)
        Force coefficients of the branch [N] (the fundamental rows are used).
    omega_lo, omega_hi : float
        Frequency range [rad/s].
    zeta_tol : float
    max_dof : int
        Larger models are skipped (returns []).

    Returns
    -------
    list of UndampedResonance
        Sorted by frequency.
    """
    from .condensation import dense_array
    from .modes import eigenmodes
    n = model.n_dof
    if not n or n > max_dof:
        return []
    lo, hi = sorted((omega_lo, omega_hi))
    M, C = dense_array(model.M), dense_array(model.C)
    lin = model.linearisation
    c = model.contacts
    # fundamental force amplitude (complex) per DOF
    F = np.asarray(F, dtype=float)
    if 1 in basis.index:
        ic, is_ = basis.index[1]
        f1 = F[ic] - 1j * F[is_]
    else:
        f1 = np.zeros(n, complex)
    Kst = dense_array(lin.K)
    systems = [("stuck", Kst)]
    mu_N = np.zeros(c.n_elements)
    Tt = dense_array(c.Tt) if c.n_elements else np.zeros((0, n))
    if c.n_elements and c.law.has_force and c.law.can_slip:
        kt = np.where(lin.closed, c.law.kt, 0.0)
        systems.append(("slipping", Kst - Tt.T @ (kt[:, None] * Tt)))
        mu_N = np.where(lin.closed, c.law.slip_force(np.maximum(lin.N, 0.0)), 0.0)
    out = []
    for joint, K in systems:
        f_hz, phi = eigenmodes(K, M, n)
        for k, fk in enumerate(np.asarray(f_hz)):
            w = 2 * np.pi * float(fk)
            if not (lo <= w <= hi) or w <= 0.0:
                continue
            p = phi[:, k] / np.sqrt(max(float(phi[:, k] @ M @ phi[:, k]), 1e-300))
            if float(p @ C @ p) / (2 * w) > zeta_tol:
                continue
            fw = float(np.pi * abs(p @ f1))
            slip = np.abs(Tt @ p)
            ffw = float(4.0 * np.sum(mu_N * slip))
            if joint == "stuck":
                # bounded when the contacts slip in it (the slipping system decides)
                unb = ffw == 0.0 and fw > 0.0
            else:
                unb = fw > ffw
            out.append(UndampedResonance(joint, w, k, fw, ffw, bool(unb)))
    return sorted(out, key=lambda r: r.omega)


def diagnose_failure(resonances, lam: float, rel: float = 0.1):
    """The undamped resonance nearest to where a branch failed, if within ``rel`` of it.

    Parameters
    ----------
    resonances : list of UndampedResonance
    lam : float
        Frequency where the branch stopped [rad/s].
    rel : float
        Largest relative distance ``|omega - lam| / omega``.

    Returns
    -------
    UndampedResonance or None
        An unbounded one is preferred over a bounded one at the same distance class.
    """
    near = [r for r in resonances if abs(r.omega - lam) <= rel * r.omega]
    if not near:
        return None
    unb = [r for r in near if r.unbounded]
    return min(unb or near, key=lambda r: abs(r.omega - lam))


def explain_branch_failure(conv, system, F, omega_lo: float, omega_hi: float, lam: float):
    """A branch's convergence, its message extended by the physical cause when it failed
    near an undamped resonance (:func:`undamped_resonances` of ``system``'s model in
    ``[omega_lo, omega_hi]`` rad/s, force coefficients ``F``; ``lam`` the branch's last
    frequency [rad/s]).

    Returns
    -------
    jointsim.results.Convergence
        ``conv`` itself when it succeeded or nothing explains it.
    """
    if conv.success:
        return conv
    if system.model.n_dof > UNDAMPED_MAX_DOF:
        log.info("the branch's failure is not checked against undamped resonances: the "
                 "model has %d DOFs (two dense eigen-decompositions are made up to %d)",
                 system.model.n_dof, UNDAMPED_MAX_DOF)
    res = undamped_resonances(system.model, system.basis, F, omega_lo, omega_hi,
                              max_dof=UNDAMPED_MAX_DOF)
    if "grows without bound" in conv.message:
        r = diagnose_failure(res, lam)
        if r is not None and r.unbounded:   # the linearised systems say why
            return Convergence(False, conv.status, f"{conv.message}; {r.describe()}",
                               conv.iterations)
        near = ", ".join(f"{r.joint} joint at omega = {r.omega:.6g}" for r in res
                         if abs(r.omega - lam) <= 0.1 * r.omega)
        return Convergence(False, conv.status, (
            f"{conv.message}: a resonance of the joint at large amplitude that nothing "
            f"damps (physics, not a numerical failure); add damping to model.C"
            + (f" (undamped linearised resonances near it: {near})" if near else "")),
            conv.iterations)
    r = diagnose_failure(res, lam)
    if r is None:
        return conv
    return Convergence(False, conv.status, f"{conv.message}; {r.describe()}", conv.iterations)


def sampled_reclosing(joint, effects) -> bool:
    """Whether re-closing sliders take their anchor at an AFT sample: an anchored slider
    law (``joint.reversal = "anchor"``, law ``jenkins`` or ``iwan4``) on a coupled,
    separating contact with ``joint.closing = "sample"``.  The residual then jumps a
    little whenever a closing instant crosses a sample (:func:`closing_advice`), and
    the FRC's continuation keeps the branch's orientation against corrector landings
    on nearby pieces of it (``keep_orientation`` of
    :class:`jointsim.solvers.continuation.Continuation`).

    Parameters
    ----------
    joint, effects : scene sections
        ``scene.joint`` and ``scene.effects``.

    Returns
    -------
    bool
    """
    return (getattr(joint, "closing", "sample") == "sample" and joint.reversal == "anchor"
            and joint.law in ("jenkins", "iwan4")
            and bool(effects.friction and effects.normal == "coupled" and effects.separation))


def closing_advice(joint, effects, message: str) -> str:
    """A failed branch's message extended by the sampled-closing advice, when it applies.

    With an anchored slider law (``joint.reversal = "anchor"``, law ``jenkins`` or
    ``iwan4``) on a coupled, separating contact and ``joint.closing = "sample"``, a
    slider that re-closes takes its anchor at the first closed AFT sample, so the
    residual jumps a little whenever a closing instant crosses a sample.  Where the
    branch folds (a near-singular Jacobian) these jumps leave nearby pieces of the
    branch that the stepper can take for the branch and zig-zag between (the coupled
    lap joint's 20 N FRC at H = 0..11, Nt = 256 near 1033 rad/s; README "Hard
    cases").  ``joint.closing = "interpolated"`` makes the residual continuous there.

    Parameters
    ----------
    joint, effects : scene sections
        ``scene.joint`` and ``scene.effects``.
    message : str
        The branch's failure message.

    Returns
    -------
    str
        ``message``, with the advice appended when the branch's corrector failed on
        such a contact (and the message does not already name the closing).
    """
    if "corrector failed" not in message or "joint.closing" in message \
            or not sampled_reclosing(joint, effects):
        return message
    return (f"{message}; this coupled, separating contact takes a re-closing slider's "
            f"anchor at the first closed AFT sample (joint.closing = 'sample'), so the "
            f"residual jumps a little whenever a closing instant crosses a sample, and "
            f"where the branch folds these jumps leave nearby pieces of it that the "
            f"continuation can zig-zag between: set joint.closing = 'interpolated' (the "
            f"residual is then continuous there), or change analysis.hbm.n_samples or "
            f"analysis.hbm.step_max")
