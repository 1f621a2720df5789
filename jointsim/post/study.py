"""The lap-joint study: numbers that compare backbones and test the Masing manifold.

Everything here reads a result file and returns plain arrays or small
dataclasses; the figures (:mod:`jointsim.post.study_plots`), ``jointsim info``
and the README table all use these functions, so every number shown comes from
one place.

* :func:`backbone_comparison` -- EPMC against QSMA (and free decay) frequency
  and damping at chosen modal amplitudes, with relative differences;
* :func:`loop_points` -- the loops stored by an analysis, with the amplitude
  (or frequency) of the solution point each belongs to; :func:`study_group` --
  the group the study reads (the EPMC's loops solved exactly at the loop
  amplitudes when the file has them);
* :func:`manifold_fractions` -- per loop set, the fraction of loaded elements
  on their manifold and on their classical Masing curve (a count);
* :func:`weighted_fractions` -- the same shares weighted by contact area or by
  the slip-limit force ``mu N0`` (:func:`fraction_weights`), which do not
  depend on the mesh;
* :func:`condition_confusion` -- whether violating the seed's Eq. 4 / Eq. 6
  predicts leaving the manifold, as a 2 x 2 table over (element, amplitude);
* :func:`control_sets`, :func:`control_fractions`, :func:`attribution` -- the
  third column: the loops' kinematics replayed through the ``manifold``
  reversal law (the control for seed condition 5, ``/<group>/control``), and
  each physical loop attributed (exhaustively) to: on its manifold, off it
  with both conditions held (condition 5), off it with Eq. 4 or Eq. 6
  violated, or off it with the control off too; with the separating pairs
  and the pairs whose manifold is clipped at ``+-mu N`` counted in each cell.

The manifold is the seed's Eq. 7 with its friction limit: the Masing
construction clipped to ``+-mu N(t)`` (:mod:`jointsim.masing`); how far the
unclipped construction leaves the limit is ``/<group>/masing/manifold_excess``.

An element is *loaded* in a loop set when its normal load is positive at some
sample; elements that stay open carry no force and are left out of fractions
and of the confusion table.
"""
from __future__ import annotations

from dataclasses import dataclass

import h5py
import numpy as np


def _interp_log(x_new, x, y):
    """Interpolate ``y(x)`` at ``x_new`` linearly in log(x); NaN outside the range."""
    x = np.asarray(x, dtype=float)
    y = np.asarray(y, dtype=float)
    ok = (x > 0) & np.isfinite(y)
    x, y = x[ok], y[ok]
    if x.size < 2:
        return np.full(np.shape(x_new), np.nan)
    order = np.argsort(x)
    x, y = x[order], y[order]
    lx = np.log(np.asarray(x_new, dtype=float))
    out = np.interp(lx, np.log(x), y, left=np.nan, right=np.nan)
    return out


@dataclass(frozen=True)
class BackboneRow:
    """EPMC and QSMA at one modal amplitude (frequencies in Hz)."""

    amplitude: float
    f_epmc: float
    f_qsma: float
    zeta_epmc: float
    zeta_qsma: float

    @property
    def df_rel(self) -> float:
        """(f_qsma - f_epmc) / f_epmc."""
        return (self.f_qsma - self.f_epmc) / self.f_epmc

    @property
    def dzeta_rel(self) -> float:
        """(zeta_qsma - zeta_epmc) / zeta_epmc."""
        return (self.zeta_qsma - self.zeta_epmc) / self.zeta_epmc


def exact_where_solved(g, amps, key, vals) -> np.ndarray:
    """``vals`` with the values the file solved exactly at an amplitude of ``amps``.

    Parameters
    ----------
    g : h5py.Group
        ``/epmc/at_amplitudes`` (:func:`jointsim.analyses.epmc_exact.exact_amplitudes`):
        ``amplitude``, ``converged`` and ``key``.
    amps : ndarray, shape (n,)
        Modal amplitudes [sqrt(kg) m].
    key : str
        ``frequency_hz`` or ``damping_ratio``.
    vals : ndarray, shape (n,)
        Values interpolated between branch points, replaced where solved exactly:
        those do not depend on where the branch placed its points.
    """
    out = np.array(vals, dtype=float)
    solved = g["amplitude"][()]
    ok = g["converged"][()]
    values = g[key][()]
    for i, am in enumerate(amps):
        hit = np.flatnonzero(np.isclose(solved, am, rtol=1e-9, atol=0.0) & ok)
        if hit.size:
            out[i] = float(values[hit[0]])
    return out


def backbone_comparison(h5: h5py.File, amplitudes) -> list[BackboneRow]:
    """EPMC and QSMA frequency and damping at the given modal amplitudes.

    Both are interpolated in log(amplitude) along their computed curves (an
    amplitude outside a curve gives NaN for it), except the EPMC values at an
    amplitude the run solved exactly (``/epmc/at_amplitudes``).

    Parameters
    ----------
    h5 : h5py.File
        A result file with ``/epmc`` and ``/qsma``.
    amplitudes : array_like
        Modal amplitudes [sqrt(kg) m].
    """
    e, q = h5["epmc"], h5["qsma"]
    amps = np.atleast_1d(np.asarray(amplitudes, dtype=float))
    fe = _interp_log(amps, e["amplitude"][()], e["frequency_hz"][()])
    ze = _interp_log(amps, e["amplitude"][()], e["damping_ratio"][()])
    if "at_amplitudes" in e:
        fe = exact_where_solved(e["at_amplitudes"], amps, "frequency_hz", fe)
        ze = exact_where_solved(e["at_amplitudes"], amps, "damping_ratio", ze)
    fq = _interp_log(amps, q["amplitude"][()], q["frequency_hz"][()])
    zq = _interp_log(amps, q["amplitude"][()], q["damping_ratio"][()])
    return [BackboneRow(float(a), float(f1), float(f2), float(z1), float(z2))
            for a, f1, f2, z1, z2 in zip(amps, fe, fq, ze, zq)]


@dataclass(frozen=True)
class LoopSets:
    """Loops an analysis stored, one set (all elements) per solution point.

    Attributes
    ----------
    group : str
        Where they are (e.g. ``epmc``).
    point : ndarray of int, shape (n_sets,)
        Solution point of each set.
    parameter : ndarray, shape (n_sets,)
        Modal amplitude of the point (EPMC), or angular frequency (HBM), or the
        set index when neither applies.
    parameter_name : str
    u, f, N : ndarray, shape (n_sets, n_e, n_samples)
    dev_manifold, dev_masing : ndarray, shape (n_sets, n_e)
    on_manifold, on_masing, eq4_ok, eq6_ok : ndarray of bool, shape (n_sets, n_e)
    loaded : ndarray of bool, shape (n_sets, n_e)
        The element's normal load is positive at some sample.
    separating : ndarray of bool, shape (n_sets, n_e)
        Loaded, and the normal load is <= 0 at some sample (the element opens).
    manifold_excess : ndarray, shape (n_sets, n_e)
        How far the unclipped manifold construction leaves ``+-mu N``
        (normalised by max ``mu N``); NaN for files written before the clip.
    """

    group: str
    point: np.ndarray
    parameter: np.ndarray
    parameter_name: str
    u: np.ndarray
    f: np.ndarray
    N: np.ndarray
    dev_manifold: np.ndarray
    dev_masing: np.ndarray
    on_manifold: np.ndarray
    on_masing: np.ndarray
    eq4_ok: np.ndarray
    eq6_ok: np.ndarray
    loaded: np.ndarray
    separating: np.ndarray | None = None
    manifold_excess: np.ndarray | None = None

    @property
    def clipped(self) -> np.ndarray:
        """The manifold is held at ``+-mu N`` somewhere (excess > 1e-12), shape (n_sets, n_e)."""
        return self.manifold_excess > 1e-12


def loop_groups(h5: h5py.File) -> list[str]:
    """Prefixes under which loops are stored (``""`` for the root)."""
    found = [prefix for prefix in ("epmc", "hbm", "transient", "prescribed")
             if f"{prefix}/loops/u" in h5 and f"{prefix}/masing/dev_manifold" in h5]
    if not found and "loops/u" in h5 and "masing/dev_manifold" in h5:
        found.append("")  # files written before loops had their own groups
    return found


#: Where the EPMC keeps the loop sets of its exact solutions at the loop amplitudes
#: (:func:`jointsim.analyses.epmc_exact.solve_at_amplitudes`).
EXACT_LOOPS = "epmc/at_amplitudes"


def exact_loop_group(h5: h5py.File, prefix: str) -> str:
    """``prefix``, or for ``"epmc"`` the group of the loop sets solved exactly at the
    loop amplitudes when the file has them (their shares do not move with where the
    branch placed its points)."""
    if prefix == "epmc" and f"{EXACT_LOOPS}/loops/u" in h5 \
            and f"{EXACT_LOOPS}/masing/dev_manifold" in h5:
        return EXACT_LOOPS
    return prefix


def study_group(h5: h5py.File) -> str | None:
    """The loop group the study reads: the EPMC's loops (its sets solved exactly at the
    loop amplitudes when the file has them, :func:`exact_loop_group`), else the first
    of :func:`loop_groups`; None when the file has no loops."""
    groups = loop_groups(h5)
    prefix = "epmc" if "epmc" in groups else (groups[0] if groups else None)
    return None if prefix is None else exact_loop_group(h5, prefix)


def loop_points(h5: h5py.File, prefix: str = "epmc") -> LoopSets:
    """Read the loop sets stored under ``prefix`` (``""``: the root ``/loops``)."""
    p = f"{prefix}/" if prefix else ""
    L, M = h5[f"{p}loops"], h5[f"{p}masing"]
    point = L["point"][()] if "point" in L else np.arange(L["u"].shape[0])
    name, param = "set", point.astype(float)
    owner = prefix or str(L.attrs.get("analysis", ""))
    if owner == "epmc" and "epmc/amplitude" in h5:
        param, name = h5["epmc/amplitude"][()][point], "modal amplitude"
    elif owner == EXACT_LOOPS:
        param, name = h5[f"{EXACT_LOOPS}/amplitude"][()][point], "modal amplitude"
    elif owner == "hbm" and "hbm/omega" in h5:
        param, name = h5["hbm/omega"][()][point], "omega"
    N = L["N"][()]
    return LoopSets(group=prefix, point=point, parameter=np.asarray(param, dtype=float),
                    parameter_name=name, u=L["u"][()], f=L["f"][()], N=N,
                    dev_manifold=M["dev_manifold"][()], dev_masing=M["dev_masing"][()],
                    on_manifold=M["on_manifold"][()], on_masing=M["on_masing"][()],
                    eq4_ok=M["eq4_ok"][()], eq6_ok=M["eq6_ok"][()],
                    loaded=(N > 0.0).any(axis=2),
                    separating=(N > 0.0).any(axis=2) & (N <= 0.0).any(axis=2),
                    manifold_excess=(M["manifold_excess"][()] if "manifold_excess" in M
                                     else np.full(N.shape[:2], np.nan)))


def manifold_fractions(sets: LoopSets):
    """Fraction of loaded elements on their manifold and on classical Masing.

    A count: its meaning changes with the number of elements (the mesh);
    :func:`weighted_fractions` gives the mesh-independent shares.

    Returns
    -------
    on_manifold, on_masing : ndarray, shape (n_sets,)
        NaN for a set without loaded elements.
    n_loaded : ndarray of int, shape (n_sets,)
    """
    n = sets.loaded.sum(axis=1)
    man, mas, _ = weighted_fractions(sets, np.ones(sets.loaded.shape[1]))
    return man, mas, n


def weighted_fractions(sets: LoopSets, weights):
    """Weighted share of the loaded elements on their manifold and on classical Masing.

    ``sum(w_e over loaded elements on the manifold) / sum(w_e over loaded
    elements)``, per loop set.  With the contact area as weight it is the
    share of the loaded contact area; with the slip-limit force ``mu N0``,
    the share of the joint's friction capacity.  Both converge with the
    mesh, unlike the element count.

    Parameters
    ----------
    sets : LoopSets
    weights : array_like, shape (n_e,)
        Non-negative weight of each element.

    Returns
    -------
    on_manifold, on_masing : ndarray, shape (n_sets,)
        NaN for a set whose loaded elements weigh nothing.
    total : ndarray, shape (n_sets,)
        Total weight of the loaded elements.
    """
    w = np.asarray(weights, dtype=float)
    if w.shape != (sets.loaded.shape[1],):
        raise ValueError(f"weights must have shape ({sets.loaded.shape[1]},), got {w.shape}")
    lw = sets.loaded * w
    total = lw.sum(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        man = (sets.on_manifold * lw).sum(axis=1) / total
        mas = (sets.on_masing * lw).sum(axis=1) / total
    return np.where(total > 0, man, np.nan), np.where(total > 0, mas, np.nan), total


def fraction_weights(h5: h5py.File, n_elements: int) -> dict:
    """Element weights for :func:`weighted_fractions` available in a result file.

    Returns
    -------
    dict
        ``"area"``: ``/contacts/area`` [m^2]; ``"mu N0"``: ``/contacts/mu``
        times ``/static/N`` [N] (the slip-limit force at the preload).  Only
        the ones the file has, with ``n_elements`` entries.
    """
    out = {}
    if "contacts/area" in h5 and h5["contacts/area"].shape == (n_elements,):
        out["area"] = h5["contacts/area"][()]
    if "contacts/mu" in h5 and "static/N" in h5 and h5["static/N"].shape == (n_elements,):
        mu = np.broadcast_to(np.asarray(h5["contacts/mu"][()], dtype=float).reshape(-1)
                             if np.size(h5["contacts/mu"]) in (1, n_elements)
                             else np.nan, (n_elements,))
        out["mu N0"] = mu * np.maximum(h5["static/N"][()], 0.0)
    return out


@dataclass(frozen=True)
class Confusion:
    """Do the seed's conditions predict leaving the manifold?

    Counts over (element, loop set) pairs of loaded elements:
    ``predicted`` = Eq. 4 or Eq. 6 violated; ``off`` = not on the manifold.
    """

    violated_off: int
    violated_on: int
    holds_off: int
    holds_on: int

    @property
    def total(self) -> int:
        return self.violated_off + self.violated_on + self.holds_off + self.holds_on

    @property
    def precision(self) -> float:
        """Of the pairs that violate a condition, the share that is off the manifold."""
        v = self.violated_off + self.violated_on
        return self.violated_off / v if v else float("nan")

    @property
    def recall(self) -> float:
        """Of the pairs off the manifold, the share that violates a condition."""
        o = self.violated_off + self.holds_off
        return self.violated_off / o if o else float("nan")

    def table(self) -> str:
        return "\n".join([
            f"{'':22} {'off manifold':>13} {'on manifold':>12}",
            f"{'Eq. 4 or 6 violated':22} {self.violated_off:>13d} {self.violated_on:>12d}",
            f"{'both conditions hold':22} {self.holds_off:>13d} {self.holds_on:>12d}",
            f"precision {self.precision:.3f}, recall {self.recall:.3f} "
            f"({self.total} element-amplitude pairs)"])


def condition_confusion(sets: LoopSets) -> Confusion:
    """Cross the condition checks with the on-manifold flags (loaded elements only)."""
    m = sets.loaded
    violated = ~(sets.eq4_ok & sets.eq6_ok)
    off = ~sets.on_manifold
    return Confusion(violated_off=int((m & violated & off).sum()),
                     violated_on=int((m & violated & ~off).sum()),
                     holds_off=int((m & ~violated & off).sum()),
                     holds_on=int((m & ~violated & ~off).sum()))


@dataclass(frozen=True)
class ControlSets:
    """The manifold-law replay of a group's loops (``/<group>/control``).

    Attributes
    ----------
    dev_manifold, excess, periodicity, replay_error : ndarray, shape (n_sets, n_e)
        See :class:`jointsim.masing.ControlReport` (normalised by max ``mu N``);
        ``dev_manifold`` is against the clipped manifold, ``excess`` how far
        the unclipped construction leaves ``+-mu N``.
    on_manifold : ndarray of bool, shape (n_sets, n_e)
    cause : ndarray of int, shape (n_sets, n_e)
        Codes of :data:`jointsim.masing.CAUSE_NAMES`.
    tol : float
    """

    dev_manifold: np.ndarray
    excess: np.ndarray
    periodicity: np.ndarray
    replay_error: np.ndarray
    on_manifold: np.ndarray
    cause: np.ndarray
    tol: float

    @property
    def admissible(self) -> np.ndarray:
        """The control's unclipped manifold construction lies inside ``+-mu N``
        (excess <= tol), shape (n_sets, n_e)."""
        return self.excess <= self.tol


def control_sets(h5: h5py.File, prefix: str = "epmc") -> ControlSets | None:
    """Read ``/<prefix>/control``; None when the file has none."""
    g = f"{prefix}/control" if prefix else "control"
    if g not in h5:
        return None
    c = h5[g]
    return ControlSets(dev_manifold=c["dev_manifold"][()], excess=c["excess"][()],
                       periodicity=c["periodicity"][()], replay_error=c["replay_error"][()],
                       on_manifold=c["on_manifold"][()], cause=c["cause"][()].astype(int),
                       tol=float(c.attrs.get("tol", 0.01)))


def control_fractions(sets: LoopSets, control: ControlSets):
    """Per loop set, shares of the loaded elements: control on its (clipped) manifold,
    control's unclipped manifold construction inside ``mu N``; and the control's
    largest deviation where its loop closes (round-off by construction).

    Returns
    -------
    on, admissible : ndarray, shape (n_sets,)
    dev_max : ndarray, shape (n_sets,)
        0 when no element qualifies.
    """
    m = sets.loaded
    n = np.maximum(m.sum(axis=1), 1)
    on = (control.on_manifold & m).sum(axis=1) / n
    adm = (control.admissible & m).sum(axis=1) / n
    closed = m & (control.periodicity <= 1e-12)
    dev = np.where(closed, control.dev_manifold, 0.0).max(axis=1)
    return on, adm, dev


#: Rows of :class:`Attribution`: the seed's conditions on the physical loop.
ATTRIBUTION_ROWS = ("Eq. 4 or 6 violated", "both conditions hold")


@dataclass(frozen=True)
class Attribution:
    """Exhaustive attribution of the (element, loop set) pairs of loaded elements.

    Attributes
    ----------
    columns : tuple of str
        Causes (:data:`jointsim.masing.CAUSE_NAMES` without ``unloaded``).
    count, separating, clipped : ndarray of int, shape (2, n_columns)
        Pairs per (row of :data:`ATTRIBUTION_ROWS`, cause); of those, the
        ones whose element separates during the period; and the ones whose
        physical manifold is held at ``+-mu N`` somewhere (its unclipped
        construction leaves the limit, ``manifold_excess > 1e-12``; -1 when
        the file has no excess).
    """

    columns: tuple
    count: np.ndarray
    separating: np.ndarray
    clipped: np.ndarray

    @property
    def total(self) -> int:
        return int(self.count.sum())

    def cell(self, i: int, j: int) -> str:
        """``n (s sep, c clip)``, or ``-`` for an empty cell."""
        n = int(self.count[i, j])
        if n == 0:
            return "-"
        clip = "" if self.clipped[i, j] < 0 else f", {int(self.clipped[i, j])} clip"
        return f"{n} ({int(self.separating[i, j])} sep{clip})"

    def table(self, width: int = 20) -> list[str]:
        """Text rows: conditions against causes, with a total row."""
        lines = [f"{'':22}" + "".join(f" {c:>{width}}" for c in self.columns)]
        tot = Attribution(self.columns, self.count.sum(axis=0, keepdims=True),
                          self.separating.sum(axis=0, keepdims=True),
                          np.where((self.clipped < 0).any(axis=0, keepdims=True), -1,
                                   self.clipped.sum(axis=0, keepdims=True)))
        for label, obj, i in [(ATTRIBUTION_ROWS[0], self, 0), (ATTRIBUTION_ROWS[1], self, 1),
                              ("total", tot, 0)]:
            lines.append(f"{label:22}" + "".join(
                f" {obj.cell(i, j):>{width}}" for j in range(len(self.columns))))
        return lines


def attribution(sets: LoopSets, control: ControlSets) -> Attribution:
    """Attribute every (element, loop set) pair of loaded elements.

    A pair is *on manifold* when the physical loop is on its (clipped)
    manifold; otherwise it is *condition 5* when Eq. 4 and Eq. 6 hold and the
    control is on its manifold (the physical reference force does not follow
    N, seed Section 3.1), *Eq. 4/Eq. 6* when a condition is violated and the
    control is on its manifold, and *control off* when the control itself did
    not close on its manifold (nothing attributed).  The four columns are
    exhaustive; every cell also counts its separating pairs and the pairs
    whose manifold is held at ``+-mu N``.

    Returns
    -------
    Attribution
    """
    from ..masing import CAUSE_NAMES, CAUSE_UNLOADED

    m = sets.loaded
    violated = ~(sets.eq4_ok & sets.eq6_ok)
    codes = [k for k in range(len(CAUSE_NAMES)) if k != CAUSE_UNLOADED]
    sep = sets.separating if sets.separating is not None else np.zeros_like(m)
    have_exc = sets.manifold_excess is not None and np.isfinite(sets.manifold_excess[m]).all()
    clip = sets.clipped if have_exc else np.zeros_like(m)
    count = np.zeros((2, len(codes)), dtype=np.int64)
    nsep, nclip = count.copy(), count.copy()
    for i, rows in enumerate((violated, ~violated)):
        for j, k in enumerate(codes):
            cell = m & rows & (control.cause == k)
            count[i, j] = cell.sum()
            nsep[i, j] = (cell & sep).sum()
            nclip[i, j] = (cell & clip).sum() if have_exc else -1
    return Attribution(tuple(CAUSE_NAMES[k] for k in codes), count, nsep, nclip)


def control_text(sets: LoopSets, control: ControlSets) -> list[str]:
    """The third column's lines for :func:`study_text`."""
    on, adm, dev = control_fractions(sets, control)
    lines = ["  Third column: the loops' (u, N) replayed through the manifold reversal law "
             "(control for seed condition 5); loaded elements:",
             f"    {sets.parameter_name:>15} {'physical on':>12} {'control on':>11} "
             f"{'ctrl unclipped in mu N':>23} {'control dev (closed)':>21}"]
    phys, _, _ = manifold_fractions(sets)
    for i in range(sets.u.shape[0]):
        lines.append(f"    {sets.parameter[i]:>15.4g} {phys[i]:>12.2f} {on[i]:>11.2f} "
                     f"{adm[i]:>23.2f} {dev[i]:>21.2g}")
    att = attribution(sets, control)
    lines.append(f"  Attribution of the physical loops ({att.total} element-amplitude pairs; "
                 "rows: the seed's conditions, columns: cause; in brackets: separating, "
                 "manifold clipped at +-mu N):")
    lines.extend("    " + s for s in att.table())
    return lines


def study_text(h5: h5py.File) -> str:
    """The headline numbers of a study run, for ``jointsim info``."""
    lines = []
    prefix = study_group(h5)
    sets = loop_points(h5, prefix) if prefix is not None else None
    if all(k in h5 and h5[k].shape[0] for k in ("epmc/amplitude", "qsma/amplitude")):
        # both curves hold points (a failed or interrupted run may have an empty group)
        amps = sets.parameter if sets is not None and prefix in ("epmc", EXACT_LOOPS) else \
            np.logspace(*np.log10(np.percentile(h5["epmc/amplitude"][()], [10, 90])), 3)
        lines.append("  EPMC against QSMA (frequencies in Hz):")
        lines.append(f"    {'amplitude':>11} {'f_EPMC':>10} {'f_QSMA':>10} {'df':>8} "
                     f"{'zeta_EPMC':>10} {'zeta_QSMA':>10} {'dzeta':>8}")
        for r in backbone_comparison(h5, amps):
            lines.append(f"    {r.amplitude:>11.3e} {r.f_epmc:>10.4f} {r.f_qsma:>10.4f} "
                         f"{100 * r.df_rel:>7.2f}% {r.zeta_epmc:>10.3e} {r.zeta_qsma:>10.3e} "
                         f"{100 * r.dzeta_rel:>7.1f}%")
    if sets is not None and sets.u.shape[0]:
        man, mas, n = manifold_fractions(sets)
        weighted = {name: weighted_fractions(sets, w)
                    for name, w in fraction_weights(h5, sets.loaded.shape[1]).items()}
        lines.append(f"  Masing manifold ({prefix or 'root'} loops; loaded elements; "
                     "fractions on the manifold / on classical Masing by element count"
                     + "".join(f", by {name}" for name in weighted) + "):")
        head = f"    {sets.parameter_name:>15} {'loaded':>7} {'count':>11}"
        head += "".join(f" {'by ' + name:>11}" for name in weighted)
        lines.append(head + f" {'max dev_man':>12}")
        n_sets = sets.u.shape[0]
        shown = np.unique(np.linspace(0, n_sets - 1, min(n_sets, 12)).astype(int))
        if shown.size < n_sets:
            lines.append(f"    ({shown.size} of {n_sets} loop sets shown)")
        for i in shown:
            dm = sets.dev_manifold[i][sets.loaded[i]]
            row = f"    {sets.parameter[i]:>15.4g} {n[i]:>7d} {man[i]:>5.2f}/{mas[i]:<5.2f}"
            row += "".join(f" {wm[i]:>5.2f}/{ws[i]:<5.2f}" for wm, ws, _ in weighted.values())
            lines.append(row + f" {dm.max() if dm.size else 0.0:>12.3g}")
        conf = condition_confusion(sets)
        if np.isfinite(conf.precision) or np.isfinite(conf.recall):
            # only with data: some pair violates a condition or leaves the manifold
            lines.append("  Do Eq. 4 / Eq. 6 violations predict leaving the manifold?")
            lines.extend("    " + s for s in conf.table().splitlines())
        control = control_sets(h5, prefix)
        if control is not None and control.cause.shape == sets.loaded.shape:
            lines.extend(control_text(sets, control))
    return "\n".join(lines)
