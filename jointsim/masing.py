"""The Masing-manifold check of steady hysteresis loops (DESIGN §2).

For each element and steady period, with samples ``(u_k, f_k, N_k)``:

* the period is rolled to start at the global maximum of ``u``; reversals are
  where ``du`` changes sign, and a stack of reversals applies Masing's third
  rule (an inner loop that closes is popped), see
  :func:`jointsim._masing_kernels.references`;
* with ``(u_r, f_r, N_r)`` the governing reversal and
  ``s = sign(u_k - u_r)``, the constructions are

  - manifold: ``F_man = f_r N_k / N_r + 2 s f_bb(|u_k - u_r| / 2; N_k)``
    (the first term is 0 when ``N_r <= 0``, and ``N_k < 0`` counts as 0:
    separated);
  - classical Masing: ``F_mas = f_r + 2 s f_bb(|u_k - u_r| / 2; Nbar)``,
    ``Nbar`` the period mean of ``N``;

* the manifold prediction is its construction clipped to the friction
  limit of the sample, ``f_man = clip(F_man, -mu N_k, mu N_k)`` (laws that
  can slip): the seed's Eq. 7 with its second case, ``mu N(t) sign(u -
  u_0)`` once the first case would leave ``+-mu N(t)``.  A reversal taken
  while separated (``N_r <= 0``, the reloading branch asks for up to
  ``2 mu N``) or in microslip with N differing between the outer reversals
  makes the unclipped construction leave the limit; how far is kept as a
  diagnostic, ``manifold_excess = max_k (|F_man| - mu N_k)_+ / max_k mu N_k``;
* the classical Masing prediction is not clipped: ``f_mas = F_mas``.  It is
  the constant-N prediction (what QSMA assumes), which knows nothing of
  N(t); at constant N the clip would be a no-op for it and for the manifold
  alike (from a stack of reversals a Jenkins or Iwan Masing curve saturates
  at ``+-mu N`` by itself, tested), so the two predictions still coincide
  there.  ``masing_excess`` (defined like ``manifold_excess``) says how far
  it leaves ``+-mu N(t)`` under varying N;
* each deviation is ``max_k |f_k - f_pred| / max_k (mu N_k)``;
* the seed's conditions are checked along the loop, with ``s`` the distance
  travelled from the last reversal and ``kt`` the element's stuck stiffness:

  - Eq. 4, ``d(mu N)/ds >= -kt`` on intervals that start with the force still
    opposing the motion (after a reversal, before the force changes sign);
  - Eq. 6, ``d(mu N)/ds <= kt`` on intervals that start slipping.

  A condition holds when no checked interval violates it.  Its margin
  converges as the sampling is refined (issue 14):

  - held: the smallest relative slack, ``eq4_margin = min(1 + rate/kt)``,
    ``eq6_margin = min(1 - rate/kt)`` (>= 0);
  - violated: minus the integrated violation normalised by ``kt`` and the
    loop size, ``-sum max(0, -d(mu N) - kt ds) / (kt (max u - min u))``
    (Eq. 6: ``d(mu N) - kt ds``) over the checked intervals (< 0): the
    fraction of the loop's stiffness-times-travel by which ``mu N`` falls
    (rises) faster than the elastic force can follow.  The pointwise rate is
    not used there, since at a reversal ``ds -> 0`` and any ``dN/dt != 0``
    makes it grow without bound as the sampling is refined;
  - ``inf`` when no interval was checked.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ._masing_kernels import references
from .contact._kernels import march_manifold_periodic

#: Relative closeness to ``mu N`` that counts as slipping.
SLIP_RTOL = 1e-9


@dataclass(frozen=True)
class MasingReport:
    """Masing-manifold check of ``n_e`` element loops over one period.

    Attributes
    ----------
    f_manifold, f_masing : ndarray, shape (n_e, n)
        Predicted forces [N] (the manifold's clipped to ``+-mu N``), in the
        original sample order.
    dev_manifold, dev_masing : ndarray, shape (n_e,)
        Normalised deviations [-].
    manifold_excess, masing_excess : ndarray, shape (n_e,)
        How far the unclipped manifold construction (the classical Masing
        prediction) leaves ``+-mu N``,
        ``max_k (|F_k| - mu N_k)_+ / max_k mu N_k`` [-] (0 inside the limit).
    on_manifold, on_masing : ndarray of bool, shape (n_e,)
        ``dev <= tol``.
    eq4_ok, eq6_ok : ndarray of bool, shape (n_e,)
    eq4_margin, eq6_margin : ndarray, shape (n_e,)
        Margins of the seed's Eq. 4 and Eq. 6 (>= 0 means satisfied): the
        smallest relative slack when held, minus the normalised integrated
        violation when violated (see the module doc); both converge with
        the sampling.
    n_reversals : ndarray of int, shape (n_e,)
        Reversals of ``u`` in the period.
    tol : float
    """

    f_manifold: np.ndarray
    f_masing: np.ndarray
    dev_manifold: np.ndarray
    dev_masing: np.ndarray
    on_manifold: np.ndarray
    on_masing: np.ndarray
    eq4_ok: np.ndarray
    eq6_ok: np.ndarray
    eq4_margin: np.ndarray
    eq6_margin: np.ndarray
    n_reversals: np.ndarray
    tol: float
    manifold_excess: np.ndarray | None = None
    masing_excess: np.ndarray | None = None


def check_loops(u, f, N, law, tol: float = 0.01) -> MasingReport:
    """Check steady loops against their Masing manifolds.

    Parameters
    ----------
    u, f, N : array_like, shape (n_e, n)
        Tangential displacement [m], tangential force [N] and normal load [N]
        over one steady period.
    law : jointsim.contact.TangentialLaw
        The elements' law, which gives the backbone ``f_bb(x; N)``, the
        macroslip force ``mu N`` and the stuck stiffness ``kt``.
    tol : float
        On-manifold tolerance on the normalised deviation.

    Returns
    -------
    MasingReport
    """
    u = np.atleast_2d(np.asarray(u, dtype=float))
    f = np.atleast_2d(np.asarray(f, dtype=float))
    N = np.atleast_2d(np.asarray(N, dtype=float))
    if not (u.shape == f.shape == N.shape):
        raise ValueError(f"u, f, N must have one shape, got {u.shape}, {f.shape}, {N.shape}")
    ne, n = u.shape
    if law.n_elements != ne:
        raise ValueError(f"law has {law.n_elements} elements, loops have {ne}")

    # roll every row so that it starts at its global maximum of u
    start = np.argmax(u, axis=1)
    idx = (start[:, None] + np.arange(n)[None, :]) % n
    rows = np.arange(ne)[:, None]
    ur, fr, Nr = u[rows, idx], f[rows, idx], N[rows, idx]
    ref, branch = references(np.ascontiguousarray(ur))

    u_ref = np.take_along_axis(ur, ref, axis=1)
    f_ref = np.take_along_axis(fr, ref, axis=1)
    N_ref = np.take_along_axis(Nr, ref, axis=1)
    delta = ur - u_ref
    s = np.sign(delta)
    half = 0.5 * np.abs(delta)

    with np.errstate(divide="ignore", invalid="ignore"):
        # a negative sample of N means separation: no load, no reference force
        scale = np.where(N_ref > 0.0, np.maximum(Nr, 0.0) / N_ref, 0.0)
    raw_man = f_ref * scale + 2.0 * s * law.backbone(half, Nr)
    Nbar = Nr.mean(axis=1, keepdims=True)
    raw_mas = f_ref + 2.0 * s * law.backbone(half, np.broadcast_to(Nbar, Nr.shape))

    slip = law.slip_force(Nr)
    norm = slip.max(axis=1)
    norm_safe = np.where(norm > 0.0, norm, 1.0)
    if law.can_slip:
        # seed Eq. 7, second case: the branch is held at the friction limit
        f_man = np.clip(raw_man, -slip, slip)
        f_mas = raw_mas  # the constant-N prediction: no knowledge of N(t)
        exc_man = np.maximum(np.abs(raw_man) - slip, 0.0).max(axis=1) / norm_safe
        exc_mas = np.maximum(np.abs(raw_mas) - slip, 0.0).max(axis=1) / norm_safe
    else:
        f_man, f_mas = raw_man, raw_mas
        exc_man = exc_mas = np.zeros(ne)
    dev_man = np.abs(fr - f_man).max(axis=1) / norm_safe
    dev_mas = np.abs(fr - f_mas).max(axis=1) / norm_safe

    eq4_margin, eq6_margin = _conditions(ur, fr, slip, law.kt)

    # undo the roll for the per-sample predictions
    inv = np.empty_like(idx)
    inv[rows, idx] = np.arange(n)[None, :]
    n_rev = (np.diff(branch, axis=1) != 0).sum(axis=1)  # branch[0] = 0 counts the max
    n_rev = np.where(np.ptp(u, axis=1) > 0.0, n_rev, 0)
    return MasingReport(
        f_manifold=f_man[rows, inv], f_masing=f_mas[rows, inv],
        dev_manifold=dev_man, dev_masing=dev_mas,
        on_manifold=dev_man <= tol, on_masing=dev_mas <= tol,
        eq4_ok=eq4_margin >= 0.0, eq6_ok=eq6_margin >= 0.0,
        eq4_margin=eq4_margin, eq6_margin=eq6_margin,
        n_reversals=n_rev.astype(np.int64), tol=float(tol),
        manifold_excess=exc_man, masing_excess=exc_mas)


def _conditions(u, f, slip, kt):
    """Margins of the seed's Eq. 4 and Eq. 6 along rolled loops (see module doc)."""
    du = np.diff(u, axis=1, append=u[:, :1])
    dslip = np.diff(slip, axis=1, append=slip[:, :1])
    moving = du != 0.0
    d = np.sign(du)
    with np.errstate(divide="ignore", invalid="ignore"):
        rate = np.where(moving, dslip / np.abs(du), 0.0)  # d(mu N)/ds
    at_limit = np.abs(f) >= slip * (1.0 - SLIP_RTOL)
    loaded = slip > 0.0
    unloading = moving & loaded & (f * d < 0.0)  # force still opposes the motion
    slipping = moving & loaded & at_limit & (f * d > 0.0)
    kt = np.asarray(kt, dtype=float)[:, None]
    with np.errstate(divide="ignore", invalid="ignore"):
        rel = rate / kt
    eq4 = np.where(unloading, 1.0 + rel, np.inf).min(axis=1)
    eq6 = np.where(slipping, 1.0 - rel, np.inf).min(axis=1)
    # violated: integrated violation, which converges with the sampling
    ds = np.abs(du)
    v4 = np.where(unloading, np.maximum(-dslip - kt * ds, 0.0), 0.0).sum(axis=1)
    v6 = np.where(slipping, np.maximum(dslip - kt * ds, 0.0), 0.0).sum(axis=1)
    size = kt[:, 0] * np.ptp(u, axis=1)
    size = np.where(size > 0.0, size, 1.0)
    eq4 = np.where(eq4 < 0.0, -v4 / size, eq4)
    eq6 = np.where(eq6 < 0.0, -v6 / size, eq6)
    return eq4, eq6


#: Codes of :attr:`ControlReport.cause` (the attribution of a physical departure).
CAUSE_ON, CAUSE_CONDITION5, CAUSE_EQ46, CAUSE_CONTROL_OFF, CAUSE_UNLOADED = 0, 1, 2, 3, 4
#: Their names, in code order (stored with the HDF5 dataset).
CAUSE_NAMES = ("on manifold", "condition 5", "Eq. 4/Eq. 6", "control off", "unloaded")

#: Deviation of the control loop from its (clipped) manifold beyond its
#: non-periodicity that is a bug, not round-off (normalised by max ``mu N``).
CONTROL_ROUNDOFF = 1e-9


@dataclass(frozen=True)
class ControlReport:
    """The study's third column: loops replayed through the manifold law.

    The physical loops' kinematics ``(u(t), N(t))`` are replayed, per element,
    through the ``manifold`` reversal law (:class:`~jointsim.contact.laws.ManifoldBank`,
    seed condition 5 with Masing's memory rule) and through the physical law,
    by prescribed motion with the existing kernels.

    Attributes
    ----------
    f : ndarray, shape (n_e, n)
        Manifold-law force over the replayed steady period [N].
    report : MasingReport
        The Masing check of the control loops (``report.dev_manifold`` is the
        control's deviation).
    excess : ndarray, shape (n_e,)
        How far the control loop's unclipped manifold construction leaves
        ``+-mu N`` (:attr:`MasingReport.manifold_excess` of the control), 0
        where it lies inside the limit.  Where it is > 0 the manifold follows
        the limit there (seed Eq. 7, second case), and so does the control.
    periodicity : ndarray, shape (n_e,)
        Change of the control force between the last two replayed periods,
        normalised by max ``mu N``.
    replay_error : ndarray, shape (n_e,)
        ``max |f_physical replayed - f stored| / max mu N``: how well the
        physical law, replayed, reproduces the stored (AFT) loop.  Round-off,
        except for an element that re-closes in the period and sticks at
        closing under ``joint.closing = "interpolated"``: the AFT then takes its
        anchor at the closing instant interpolated from the gap (:func:`jointsim.contact._aft_kernels.closing_anchor`),
        which the stored ``(u, N)`` samples do not carry, and the replay at the
        last open sample.
    cause : ndarray of int8, shape (n_e,)
        Attribution of the physical loop (:data:`CAUSE_NAMES`), exhaustive:
        on its manifold; off it with both Eq. 4 and Eq. 6 held while the
        control is on it (condition 5 alone: the physical reference force
        does not follow N); off it with Eq. 4 or Eq. 6 violated while the
        control is on it; off it while the control is off too (the control
        loop did not close within the replayed periods, so nothing can be
        attributed); unloaded (N <= 0 over the period).
    periods : int
        Most periods any element's control marched.
    """

    f: np.ndarray
    report: MasingReport
    excess: np.ndarray
    periodicity: np.ndarray
    replay_error: np.ndarray
    cause: np.ndarray
    periods: int = 0


def control_law(law):
    """The manifold reversal law with the sliders of ``law``; None for a law that cannot slip."""
    from .contact.laws import ManifoldBank, SliderBank

    if not (isinstance(law, SliderBank) and law.can_slip):
        return None
    return ManifoldBank(k=law.k, g=law.g, mu=law.mu)


def replay_control(u, f, N, law, physical, tol: float = 0.01, max_periods: int = 400,
                   block: int = 20, periodic_tol: float = 1e-12) -> ControlReport | None:
    """Replay steady loops through the manifold law and attribute the physical departures.

    Both laws start from rest at ``u = 0`` (where the AFT kernels start) and
    march whole periods of the stored samples.  Each element's control is
    checked every ``block`` periods and stops once its force repeats to
    ``periodic_tol`` (relative to its max ``mu N``) or ``max_periods`` were
    marched (:func:`jointsim.contact._kernels.march_manifold_periodic`); its
    last period is kept.  The
    control need not close quickly: under a varying N an element that does
    not slip has no closed loop on its manifold inside ``+-mu N`` (its scaled
    reference force drifts by about ``kt (max u - min u) (N_max / N_min - 1)``
    a cycle until the manifold reaches ``mu N``, where the clipped branch
    slips and closes the loop), which :attr:`ControlReport.periodicity`
    (non-closure) and :attr:`ControlReport.excess` (the clip) report.

    Parameters
    ----------
    u, f, N : array_like, shape (n_e, n)
        One steady period of each element [m], [N], [N], as stored.
    law : jointsim.contact.TangentialLaw
        The physical law of the loops.
    physical : MasingReport or object
        The Masing check of the stored loops; only ``on_manifold``,
        ``eq4_ok`` and ``eq6_ok`` (shape (n_e,)) are used.
    tol : float
        On-manifold tolerance.
    max_periods, block : int
    periodic_tol : float

    Returns
    -------
    ControlReport or None
        None when ``law`` cannot slip (no manifold law to compare with).

    Raises
    ------
    RuntimeError
        When a control loop is off its (clipped) manifold by more than its
        non-periodicity (plus :data:`CONTROL_ROUNDOFF`): by construction it
        cannot be.
    """
    ctrl = control_law(law)
    if ctrl is None:
        return None
    u = np.atleast_2d(np.asarray(u, dtype=float))
    f = np.atleast_2d(np.asarray(f, dtype=float))
    N = np.atleast_2d(np.asarray(N, dtype=float))
    n = u.shape[1]
    slip = law.slip_force(N)
    norm = slip.max(axis=1)
    norm = np.where(norm > 0.0, norm, 1.0)
    # the physical law: one period more than the AFT's periodic state needs is plenty
    fp = law.march(np.tile(u, 3), np.tile(N, 3), law.rest_state(N[:, 0]))[0][:, -n:]
    last, change, marched, _ = march_manifold_periodic(
        u, N, ctrl.k, ctrl.g, ctrl.rest_state(N[:, 0]), norm, block, max_periods,
        periodic_tol)
    rep = check_loops(u, last, N, ctrl, tol)
    excess = rep.manifold_excess
    loaded = (N > 0.0).any(axis=1)
    bad = loaded & (rep.dev_manifold > change + CONTROL_ROUNDOFF)
    if np.any(bad):
        e = int(np.flatnonzero(bad)[0])
        raise RuntimeError(f"manifold-law control of element {e} is off its manifold: "
                           f"dev {rep.dev_manifold[e]:.3e} > non-periodicity {change[e]:.3e}")
    cause = np.full(u.shape[0], CAUSE_ON, dtype=np.int8)
    off = ~np.asarray(physical.on_manifold, dtype=bool)
    violated = ~(np.asarray(physical.eq4_ok, dtype=bool) & np.asarray(physical.eq6_ok, dtype=bool))
    control_on = rep.dev_manifold <= tol
    cause[off & violated] = CAUSE_EQ46
    cause[off & ~violated] = CAUSE_CONDITION5
    cause[off & ~control_on] = CAUSE_CONTROL_OFF
    cause[~loaded] = CAUSE_UNLOADED
    return ControlReport(f=last, report=rep, excess=excess, periodicity=change,
                         replay_error=np.abs(fp - f).max(axis=1) / norm, cause=cause,
                         periods=int(marched.max(initial=0)))
