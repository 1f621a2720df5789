"""The harmonic preconditioner of the structured HBM Jacobian.

:class:`HarmonicPreconditioner` inverts, per harmonic, ``S_h`` plus the
harmonic-``h`` part of each element's tangent (``H + 1`` complex ``n_r x n_r``
inverses instead of one real LU of size ``n_z``), and corrects exactly for the
rest of the tangent, which lives on the elements that slip or separate during
the period, by a Woodbury (low-rank) stage; when too many elements slip, only
the largest corrections are kept and an element-block stage and GMRES do the
rest.  With the stuck joint's modal damping the per-harmonic part is formed from
the stuck flexibility instead (``MODAL_STAGE``, :mod:`jointsim.solvers.flexibility`).
Its reuse across Newton iterations and continuation steps is
:class:`~.preconditioner_cache.PreconditionerCache`.  The Jacobian itself and GMRES
are in :mod:`jointsim.solvers.jacobian`, which explains the whole scheme.
"""
from __future__ import annotations

import logging

import numpy as np
import scipy.linalg as sla

from ..linalg import PackedSymmetric, mixed_times, stacked_inverse
from .gmres import gmres_columns
from .flexibility import FlexibilitySolve, ShiftedBlock
from .hierarchical import HierarchicalInverse, schur_entries
from .lowrank_stage import (LowRankStage, RowBlocks, capacitance_blocks,
                            capacitance_coarse, capacitance_element_blocks, element_tangent)
from .tangent_projection import add_projected_tangent, project_tangent

log = logging.getLogger(__name__)

#: Add the element-block stage to the harmonic preconditioner (when its low-rank
#: correction is truncated or off).
TWO_STAGE = True
#: Correct the harmonic preconditioner exactly on the elements whose tangent couples
#: harmonics (Woodbury, :meth:`HarmonicPreconditioner._lowrank`).
LOWRANK = True
#: Largest low-rank correction: the exact one (every element whose tangent couples
#: harmonics) while it has at most ``LOWRANK_EXACT_FRACTION n_z`` coordinates and at most
#: ``LOWRANK_MAX`` (its dense ``m x m`` LU costs ``m^3``; a preconditioner cache raises
#: that limit where truncated ones fail, ``preconditioner_cache.LOWRANK_MAX_RAISED``);
#: beyond, truncated to the ``LOWRANK_MAX_FRACTION n_z`` largest.  ``LOWRANK_MIN``
#: coordinates are always allowed (small systems).  Measured in docs/hbm.md (rounds 13
#: and 14: exact up to 0.9 instead of 0.35, GMRES iterations 8,886 -> 1,837 on 96 Gauss
#: points at force 20; ``LOWRANK_MAX`` 3000 -> 4600 for the EPMC's extended systems).
LOWRANK_EXACT_FRACTION = 0.9
LOWRANK_MAX_FRACTION = 0.35
LOWRANK_MAX = 4600
LOWRANK_MIN = 600
#: The low-rank stage's LU is in single precision (half the flops and memory) for
#: Jacobians solved to this GMRES tolerance or looser: the error indicators' extended
#: systems (``INDICATOR_RTOL = 1e-3``), where a preconditioner exact to about 1e-6 still
#: solves in one or two iterations (the 121-pair EPMC's LUs were 61 of its 175 s).
SINGLE_LU_RTOL = 1e-6
#: ... and for any Jacobian once the LU is this large (``m`` coordinates), where its
#: ``m^3`` dominates the build: GMRES then needs a few more iterations to the tight
#: tolerance and the solution is the same (round 15: the force-20 branch on 96 Gauss
#: points 13.7 -> 11.7 s, X equal to 3.8e-13; docs/hbm.md).
SINGLE_LU_MIN = 1000
#: An FRC point's extended solve (loose, ``SINGLE_LU_RTOL``; one solve per
#: preconditioner, :attr:`.PreconditionerCache.single_solve`) whose low-rank stage exceeds
#: ``LOOSE_SPLIT_MIN`` coordinates keeps every row block and is solved through its
#: capacitance system (:meth:`HarmonicPreconditioner.solve_capacitance`): GMRES on
#: ``I + L_r G`` preconditioned by the inverses of its element blocks (:func:`.lowrank_stage.
#: capacitance_element_blocks`; by harmonics until round 52) and a coarse space (round 56,
#: :func:`.lowrank_stage.capacitance_coarse`), refined on the system itself; ``inf``: never
#: (round 34).  So does any other loose solve whose correction would be truncated (an
#: EPMC point's extended Newton steps, bordered and shifted: round 40).
LOOSE_SPLIT_MIN = 1000
#: ... and any loose one shared by several solves (an EPMC point's extended Newton
#: steps) whose correction exceeds this many coordinates, instead of one LU (round 52:
#: the 96-point EPMC's indicators kept up to 4,092 in one LU; docs/hbm.md, "Round 52").
LOOSE_SPLIT_SHARED_MIN = 2500
#: Elements whose harmonic coupling ``|L_e|`` is below this fraction of the largest
#: tangent entry are left out of the low-rank stage (in the stuck range the AFT's
#: round-off, about 1e-12, used to fill it: 1,260 coordinates at 121 pairs).
LOWRANK_NEGLIGIBLE = 1e-9
#: For Jacobians solved to a loose tolerance (``SINGLE_LU_RTOL``: the error indicators'
#: extended systems) the harmonic stage keeps single-precision LU factors of its blocks
#: instead of their double-precision inverses: the columns of ``P_h^-1`` the low-rank
#: stage needs and each application are triangular solves (round 31: 16 blocks of 480 x
#: 480, the inverses 217 ms, the single LUs 52 ms plus 20 ms of column solves).
FACTORED_LOOSE_STAGE = True
#: A loose solve's harmonic stage (single precision: ``FACTORED_LOOSE_STAGE``, or the
#: stuck flexibility's inverses) keeps the blocks of these harmonics in double, and so
#: does ``G`` of its capacitance system (:meth:`HarmonicPreconditioner.solve_capacitance`):
#: the fundamental's, nearly singular next to a resonance, and the static one, nearly
#: singular where the joint slips (the beams' static position is then held by the soft
#: suspension springs alone).  In single precision the capacitance solves' refinement
#: diverged: at 480 Gauss points in the resonance solve of ``frc_scales`` (force 2) from
#: a relative residual 1 to 2.4e2 in six steps, after which GMRES on the system needed
#: 1.8 s; in double each step gains the 0.03 it is asked for (docs/hbm.md, "Round 46").
LOOSE_DOUBLE_HARMONICS = (0, 1)
#: From this many rows ``n_r`` the harmonic stage's explicit inverses are formed and
#: applied in single precision (complex64: half the flops and memory traffic), except
#: the fundamental's, which is nearly singular near a resonance of an FRC and in the
#: EPMC (its single inverse doubled the GMRES iterations of the 240-point force-0.02
#: branch).  Only where the preconditioner cache allows it
#: (:attr:`.PreconditionerCache.single_inverses`: an FRC branch's continuation);
#: elsewhere, where a preconditioner serves many tight solves, it cost more than it
#: saved.  Measured in docs/hbm.md, "Round 33" and "Round 34".
SINGLE_INVERSE_MIN = 200
#: A solve to this tolerance or looser (the indicators') whose low-rank stage keeps at
#: most ``SOLVED_STAGE_COLUMNS n_r`` row blocks (a column of ``P_h^-1``, i.e. a solve,
#: each) takes a harmonic stage applied by solves, no ``n_r x n_r`` array formed: from
#: ``FLEX_SOLVE_MIN_ROWS`` rows the stuck flexibility's (:class:`~jointsim.solvers.
#: flexibility.FlexibilitySolve`), else from ``HIERARCHICAL_STAGE_MIN_ROWS`` the
#: hierarchical ``S_h``'s (:class:`~jointsim.solvers.hierarchical.HierarchicalInverse`).
#: docs/hbm.md, "Round 38" and "Round 39".  Where the flexibility's series is kept
#: compressed (from ``flexibility.FLEX_HODLR_MIN_ROWS`` coordinates; columns read from
#: the HODLR) a tight solve with few columns takes it too (round 54: the 480-point FRC's
#: applications 5.0 -> 3.0 ms), and so does any loose one, shifted too, reading only the
#: rows ``G`` needs of many columns (round 55: the 480-point EPMC 3.3 -> 2.7 s a point).
SOLVED_STAGE_RTOL = SINGLE_LU_RTOL
SOLVED_STAGE_COLUMNS = 0.1
FLEX_SOLVE_MIN_ROWS = 400
HIERARCHICAL_STAGE_MIN_ROWS = 800
#: The harmonic stage from the stuck joint's flexibility where it applies
#: (:class:`~jointsim.solvers.flexibility.StuckFlexibility`; not where the low-rank stage
#: would be truncated): ``P_h = S_h + diag(k)`` formed from the stuck modes, no ``S_h``
#: and no ``n_r^3`` inverse.  With a shift (the EPMC's bordered solves): for a loose
#: solve (an EPMC point's extended Newton steps, whose correction is not truncated:
#: docs/hbm.md, "Round 51"), else only from ``SHIFTED_FLEX_MIN_ROWS`` rows and near the
#: stuck joint (at most ``SOLVED_STAGE_COLUMNS n_r`` row blocks: "Round 40").
MODAL_STAGE = True
SHIFTED_FLEX_MIN_ROWS = 400
#: From this many rows the EPMC's tight bordered solves (shifted) are built as loose ones
#: (:attr:`HarmonicPreconditioner.loose`): the stage from the stuck flexibility in single
#: precision, every row block kept and a large correction split, solved through its
#: capacitance system and refined on the system to the tight tolerance; each build costs
#: no ``n_r^3`` inverses and no LU of the correction (docs/hbm.md, "Round 56": 240 Gauss
#: points, the continuation 12.4 -> 8.3 s).  ``inf``: never.
SHIFTED_SPLIT_MIN_ROWS = 400


class HarmonicPreconditioner:
    """Per harmonic, the inverse of ``S_h`` plus the harmonic-``h`` element tangent, with an
    exact low-rank correction for the elements whose tangent couples harmonics
    (module docstring, :meth:`_lowrank`).

    Parameters
    ----------
    jac : jointsim.solvers.jacobian.HBMJacobian
        The Jacobian it is built from (its unscaled pieces).
    shift : tuple (i, u, ell), optional
        Precondition ``J + C2 R2`` instead of ``J``: a complex rank-one term
        ``sigma u ell^T`` (``u``, ``ell`` complex (n_r,)) added to the block of the
        ``i``-th harmonic, ``sigma`` scaling it to the block's largest diagonal entry.
        In real coordinates it is ``C2 R2`` with ``R2`` the rows ``Re``, ``Im`` of
        ``ell^T (X_c - i X_s)`` and ``C2`` (n_z, 2), kept as ``self.C2``.  The
        bordered EPMC solve uses it where ``J`` itself is singular (the linear range:
        the mode is its null vector), see :class:`~jointsim.solvers.jacobian.BorderedJacobian`.
    base : HarmonicPreconditioner, optional
        Share its harmonic stage (``Pinv`` or ``Plu``, the tangent projections
        ``proj``, ``S``, built at its ``omega`` and ``xi``): ``J`` is then ``P + L``
        with ``L`` the whole difference of ``jac``'s tangent from ``base``'s
        projection plus the change of ``S_h`` with the frequency.  The low-rank stage
        corrects for the first exactly; GMRES does the rest (``partial``,
        ``preconditioner_cache.SHARE_HARMONIC_STAGE``).  A shifted stage is shared with
        its shift ``C2`` (:meth:`shares_shift`; the bordering is exact for any ``C2``).
    """

    def __init__(self, jac, shift=None, base=None):
        self.jac, self.C2 = jac, None
        self._sel = None         # (proj, RowBlocks) of _few_columns, for _lowrank
        #: built as for a loose solve (single precision, split): its solves are refined
        #: on the system (a loose one, or a large shifted one: SHIFTED_SPLIT_MIN_ROWS)
        self.loose = jac.rtol >= SINGLE_LU_RTOL or (
            shift is not None and jac.n_r >= SHIFTED_SPLIT_MIN_ROWS)
        if base is not None:
            # the harmonic stage of ``base`` (S_h at its frequency, the harmonic
            # projection of its tangent): only the low-rank stage is new
            if not base.shares_shift(shift):
                raise ValueError("a harmonic stage is shared only by builds shifted on "
                                 "the same harmonic as it, or by unshifted ones")
            # (with _columns, the columns of P_h^-1 made so far)
            for name in ("Pinv", "Plu", "Psolve", "Ppacked", "_columns", "proj", "S",
                         "Pinv_double", "omega", "xi", "modal"):
                setattr(self, name, getattr(base, name))
            self.C2, shift = base.C2, base._shift
            self.partial = True
        else:
            self._harmonic_stage(shift)
            self.partial = False
        self._shift = shift
        self.lowrank = None
        self.truncated = True
        # coordinates of one element's block (its slip and gap rows, all coefficients)
        self.Tdim = jac.n_c * ((1 if jac.Juu is not None else 0)
                               + (1 if jac.JNN is not None else 0) or 1)
        if LOWRANK:
            self._lowrank()
        if TWO_STAGE and self.truncated:
            self._element_blocks()
        else:
            self.Binv = None
        self._count_flops()

    def shares_shift(self, shift) -> bool:
        """Whether a build with ``shift`` (None or ``(i, u, ell)``) may share this
        harmonic stage: both unshifted, or both shifted on the same harmonic."""
        mine = self._shift
        return (shift is None) == (mine is None) and (shift is None or shift[0] == mine[0])

    def _harmonic_stage(self, shift, modal: bool = True, by_solves: bool = True):
        """Per harmonic, the inverse of ``S_h`` plus the harmonic projection of every
        element's tangent (``self.Pinv``, complex64 from ``SINGLE_INVERSE_MIN`` rows where
        the cache allows it, with the fundamental's in double in ``self.Pinv_double``;
        or for a loose solve single-precision LU factors ``self.Plu``, but for
        ``LOOSE_DOUBLE_HARMONICS``: ``FACTORED_LOOSE_STAGE``, or a stage applied by
        solves ``self.Psolve``: ``SOLVED_STAGE_*``; ``self.proj``; ``S_h`` kept as
        ``self.S``); from the stuck flexibility instead where it applies (:meth:`_modal_stage`)."""
        jac, nr = self.jac, self.jac.n_r
        self.omega, self.xi, self.Psolve, self.Ppacked = jac.freq.omega, jac.freq.xi, None, None
        self._columns = None

        def proj():     # the complex-form projections of the (h, h) blocks, (n_h, n_e)
            return {key: None if Jb is None else np.array(
                [project_tangent(Jb, jac._ic[i], jac._is[i], h)
                 for i, h in enumerate(jac.basis.harmonics)])
                for key, Jb in (("uu", jac.Juu), ("ug", jac.Jug), ("NN", jac.JNN))}
        # a loose solve whose low-rank stage needs few columns of P_h^-1: a stage applied
        # by solves (SOLVED_STAGE_COLUMNS), the flexibility's first, else the hierarchical
        loose = by_solves and jac.rtol >= SOLVED_STAGE_RTOL and shift is None
        # shifted (the EPMC's bordered solves): built as a loose solve (its correction is
        # split, never truncated: self.loose), or a large one near the stuck joint
        loose_solve = self.loose
        flex = jac.lin.flexibility if MODAL_STAGE and modal and (
            shift is None or nr >= SHIFTED_FLEX_MIN_ROWS or loose_solve) else None
        stuck = self._stuck_proj(flex) if flex is not None else None
        self.modal = flex is not None and (shift is None or loose_solve
                                           or self._few_columns(stuck))
        nus = np.asarray(jac.basis.harmonics, dtype=float) * self.omega
        # the flexibility applied by solves (SOLVED_STAGE_COLUMNS; not a tight shifted one)
        compressed = self.modal and by_solves and nr >= FLEX_SOLVE_MIN_ROWS and (
            loose_solve or shift is None) and flex.compressed(float(nus.max())) is not None
        if compressed and loose_solve or self.modal and by_solves and shift is None and \
                nr >= FLEX_SOLVE_MIN_ROWS and (loose or compressed) and self._few_columns(stuck):
            self.S, self.Plu, self.Pinv, self.Pinv_double = None, None, None, {}
            self.proj = stuck
            self.Psolve = FlexibilitySolve(flex, nus, self.xi, None if shift is None else
                                           (shift[0], self._shifted_block(shift)))
            return
        if loose and nr >= HIERARCHICAL_STAGE_MIN_ROWS and jac.freq.hierarchical is not None \
                and self._few_columns(proj()):
            self.modal, self.S, self.Pinv, self.Plu, self.Pinv_double = False, *[None] * 3, {}
            t, n = jac.t_row, jac.n_row
            self.Psolve = HierarchicalInverse(jac.freq.hierarchical, [
                (r, c, sign * self.proj[key]) for key, r, c, sign in (
                    ("uu", t, t, 1.0), ("ug", t, n, 1.0), ("NN", n, n, -1.0))
                if self.proj[key] is not None])
            return
        if self.modal:
            return self._modal_stage(flex, stuck, shift)
        self.S = [jac.schur(i) for i in range(len(jac.basis.harmonics))]
        self.proj = proj()
        # assembled in one stacked (n_h, n_r, n_r) array (jac's read-only S_h copied once)
        blocks = np.empty((len(jac.basis.harmonics), nr, nr), dtype=complex)
        for i in range(len(jac.basis.harmonics)):
            P = blocks[i]
            P[...] = self.S[i]
            add_projected_tangent(P, jac, i, self.proj)
            if shift is not None and shift[0] == i:
                P += np.outer(*self._shift(float(np.abs(np.diag(P)).max(initial=0.0)),
                                           i, shift[1], shift[2]))
        self.Pinv, self.Plu, self.Pinv_double = None, None, {}
        if FACTORED_LOOSE_STAGE and self.loose:
            # a loose solve: single-precision LU factors (FACTORED_LOOSE_STAGE)
            dbl = self._loose_double()
            lus = [sla.lu_factor(b if i in dbl else b.astype(np.complex64),
                                 check_finite=False) for i, b in enumerate(blocks)]
            if all(np.all(np.isfinite(lu)) and np.all(np.diag(lu) != 0) for lu, _ in lus):
                self.Plu = lus
                return
        # explicit inverses, stacked (n_h, n_r, n_r): one batched product per
        # application, and the (R, R) rows and columns the low-rank stage needs; from
        # SINGLE_INVERSE_MIN rows in single precision but for the fundamental's, where
        # the cache allows it (an FRC branch's continuation)
        single = self._single_harmonics()
        if single.any():
            self.Pinv = np.empty(blocks.shape, dtype=np.complex64)
            # in double, rounded (single-precision ones cost 14 builds at 480 points)
            self.Pinv[single] = stacked_inverse(blocks[single].astype(np.complex64), True)
            exact = stacked_inverse(blocks[~single])
            self.Pinv[~single] = exact           # (applied from Pinv_double)
            self.Pinv_double = dict(zip(np.flatnonzero(~single).tolist(), exact))
        else:
            self.Pinv = stacked_inverse(blocks)
        self.Pinv[jac._h0] = self.Pinv[jac._h0].real

    def _single_harmonics(self) -> np.ndarray:
        """Which harmonics' inverses are kept in single precision (``SINGLE_INVERSE_MIN``),
        boolean (n_h,)."""
        jac = self.jac
        if jac.n_r >= SINGLE_INVERSE_MIN and jac.cache.single_inverses:
            return np.array([h != 1 for h in jac.basis.harmonics])
        return np.zeros(len(jac.basis.harmonics), dtype=bool)

    def _loose_double(self) -> np.ndarray:
        """The harmonics (indices) whose blocks a loose solve's single-precision stage
        keeps in double (``LOOSE_DOUBLE_HARMONICS``)."""
        return np.flatnonzero(np.isin(self.jac.basis.harmonics, LOOSE_DOUBLE_HARMONICS))

    def _double_harmonics(self) -> list:
        """The harmonics (indices) of a single-precision stage that are in double (G too)."""
        if self.Plu is not None:
            return [i for i, (lu, _) in enumerate(self.Plu) if lu.dtype == np.complex128]
        if self.Psolve is not None:
            return self._loose_double().tolist() if self.PinvR is None else []
        return list(self.Pinv_double)

    def _stuck_proj(self, flex) -> dict:
        """``proj`` of the stuck stiffness ``k`` (:meth:`_modal_stage`) for every harmonic."""
        jac = self.jac
        nh, ne = len(jac.basis.harmonics), len(jac.t_row)

        def stuck(rows, sign):
            return np.broadcast_to(sign * flex.k[rows].astype(complex), (nh, ne)).copy()
        return {"uu": None if jac.Juu is None else stuck(jac.t_row, 1.0),
                "ug": None if jac.Jug is None else np.zeros((nh, ne), dtype=complex),
                "NN": None if jac.JNN is None else stuck(jac.n_row, -1.0)}

    def _few_columns(self, proj) -> bool:
        """Whether, with ``P`` holding ``proj``, the low-rank stage keeps at most
        ``SOLVED_STAGE_COLUMNS n_r`` row blocks (a column of ``P_h^-1`` each); sets
        ``self.proj`` and keeps the selection for :meth:`_lowrank`.  Decided from this
        Jacobian alone: a point's indicators do not depend on the points before it."""
        self.proj = proj
        self._sel = (proj, self._selection())
        sel = self._sel[1]
        return sel is None or min(sel.most, sel.sel.size) <= SOLVED_STAGE_COLUMNS * self.jac.n_r

    def _modal_stage(self, flex, stuck, shift=None):
        """The harmonic stage from the stuck joint's flexibility (``MODAL_STAGE``): ``P_h =
        S_h + diag(k)`` with ``k`` the stuck contact stiffness, its inverses formed from
        the stuck modes (:class:`~jointsim.solvers.flexibility.StuckFlexibility`), no
        ``S_h`` formed; ``proj`` holds ``k`` for every harmonic, so the low-rank stage
        corrects for every element whose tangent is not the stuck one (``stuck``,
        :meth:`_stuck_proj`: the low-rank stage's selection for it is reused when
        :meth:`_few_columns` made it).  With a ``shift`` the shifted harmonic's block,
        ``S_h + diag(k)`` plus the shift, is inverted (the flexibility is singular there,
        where the linear mode is ``J``'s null vector)."""
        jac = self.jac
        self.S, self.Plu, self.Pinv_double = None, None, {}
        self.proj = stuck
        nus = np.asarray(jac.basis.harmonics, dtype=float) * self.omega
        shifted = None if shift is None else (
            shift[0], self._shifted_block(shift).columns(np.arange(jac.n_r)))
        loose = self.loose                       # single precision, LOOSE_DOUBLE_HARMONICS
        single = None if loose else self._single_harmonics()
        # (flex keeps them, read-only, for the builds at one frequency: copied if replaced)
        self.Pinv = flex.inverses(nus, self.xi, single=loose or bool(single.any()))
        dbl = self._loose_double() if loose else \
            np.flatnonzero(~single) if single.any() else np.zeros(0, dtype=np.intp)
        if dbl.size:                                 # these blocks in double
            Pd = flex.inverses(nus[dbl], self.xi)
            self.Pinv_double = dict(zip(dbl.tolist(), Pd))
        if shifted is not None:
            self.Pinv = self.Pinv.copy()
            self.Pinv[shifted[0]] = shifted[1]
            if shifted[0] in self.Pinv_double:
                self.Pinv_double[shifted[0]] = shifted[1]
        # a vector's product reads the upper triangles of the complex symmetric blocks
        self.Ppacked = PackedSymmetric([self.Pinv_double.get(i, P) for i, P in enumerate(
            self.Pinv)], [shifted is None or i != shifted[0] for i in range(nus.size)])

    def _shifted_block(self, shift) -> ShiftedBlock:
        """The inverse of the shifted harmonic's ``S_h + diag(k)`` plus the shift from the
        flexibility (:class:`~jointsim.solvers.flexibility.ShiftedBlock`; the
        flexibility is singular there, the linear mode ``J``'s null vector).  The shift's
        scale is the largest diagonal entry of the block's static and inertial part
        (``K_qq + diag(k) - s M_qq``; ``S_h`` is not formed)."""
        jac, i = self.jac, shift[0]
        lin, flex = jac.lin, jac.lin.flexibility
        nu = float(jac.basis.harmonics[i]) * self.omega
        s = nu * nu + 1j * nu * self.xi
        scale = float(np.abs(np.diag(lin.K["qq"]) + flex.k - s * np.diag(lin.M["qq"])).max(
            initial=0.0))
        su, ell = self._shift(scale, i, shift[1], shift[2])
        return ShiftedBlock(flex, nu, self.xi, su, ell)

    def _inverse_times(self, X) -> np.ndarray:
        """``P_h^-1 X[h]`` for every harmonic; ``X`` (n_h, n_r, k) complex."""
        if self.Psolve is not None:
            Y = self.Psolve.solve(X)
            Y[self.jac._h0] = Y[self.jac._h0].real
            return Y
        if self.Ppacked is not None and X.shape[2] == 1:
            return self.Ppacked.times(X[:, :, 0])[:, :, None]
        if self.Plu is None:
            return mixed_times(self.Pinv, self.Pinv_double, X)
        Y = np.empty(X.shape, dtype=complex)
        for i, f in enumerate(self.Plu):
            Y[i] = sla.lu_solve(f, X[i].astype(f[0].dtype, copy=False), check_finite=False)
        h0 = self.jac._h0
        Y[h0] = Y[h0].real
        return Y

    def _inverse_columns(self, cols) -> np.ndarray:
        """The columns ``cols`` of every ``P_h^-1``, shape (n_h, n_r, len(cols))."""
        if self.Plu is None and self.Psolve is None:
            C = np.ascontiguousarray(self.Pinv[:, :, cols])
            if self.Pinv_double:           # the fundamental's columns in double
                C = C.astype(complex)
                for i, Pd in self.Pinv_double.items():
                    C[i] = Pd[:, cols]
            return C
        nh, nr = len(self.jac.basis.harmonics), self.jac.n_r
        if isinstance(self.Psolve, FlexibilitySolve):      # read, not solved for
            C = self.Psolve.columns(cols)
            C[self.jac._h0] = C[self.jac._h0].real
            return C
        if self.Psolve is not None:
            E = np.zeros((nh, nr, len(cols)), dtype=complex)
            E[:, cols, np.arange(len(cols))] = 1.0
            return self._inverse_times(E)
        # single-precision LU factors: the columns solved so far are kept on the stage
        # (complex64, as solved; each column contiguous, so only the solved ones take
        # memory), shared by the partial builds on it (an EPMC point's extended Newton
        # steps select nearly the same rows; docs/hbm.md, "Round 45")
        # (the blocks in double, LOOSE_DOUBLE_HARMONICS, keep theirs in double)
        if self._columns is None:
            Cd = {i: np.empty((nr, nr), complex) for i in self._double_harmonics()}
            Ct = np.empty((nh, nr, nr), np.complex64)
            self._columns = (np.zeros(nr, dtype=bool), Ct, Cd)
        done, Ct, Cd = self._columns                               # Ct[:, j]: column j
        new = np.unique(cols[~done[cols]])
        if new.size:
            E = np.zeros((nh, nr, new.size), dtype=complex)
            E[:, new, np.arange(new.size)] = 1.0
            Y = self._inverse_times(E)
            Ct[:, new] = Y.transpose(0, 2, 1)
            for i, C in Cd.items():
                C[new] = Y[i].T
            done[new] = True
        out = Ct[:, cols].transpose(0, 2, 1).astype(complex, order="C")
        for i, C in Cd.items():
            out[i] = C[cols].T
        return out

    def _count_flops(self):
        """The cost model of the chord policy (:class:`.PreconditionerCache`).

        ``build_flops``: the ``H + 1`` complex inverses (``8 n_r^3`` each; from the stuck
        flexibility ``4 n_r^2 n_L``; hierarchical: its own count), the low-rank LU (``2/3
        m^3``) and its ``G L`` (``2 m^2 d``), the element blocks (``2 n_e d^3``).
        ``iteration_flops``: one application (two harmonic solves with the low-rank stage,
        ``8 n_r^2`` per harmonic each, its triangular solves ``2 m^2``; the element-block
        stage adds a product with ``J``), one product with ``J`` and the
        orthogonalisation (``4 n_z`` times an average Krylov dimension of 20)."""
        jac = self.jac
        nh, nr, nz = len(jac.basis.harmonics), jac.n_r, jac.n_z
        ne = len(jac.t_row)
        d = self.Tdim
        matvec = 8.0 * nh * nr ** 2 + 6.0 * ne * jac.n_c ** 2
        if self.partial:
            build = 0.0
        elif self.Psolve is not None:
            build = self.Psolve.build_flops
        elif self.modal:             # the low modes' product (flexibility.StuckFlexibility)
            build = 4.0 * nh * nr ** 2 * jac.lin.flexibility.n_summed \
                + (8.0 * nr ** 3 if self.C2 is not None else 0.0)
        else:
            build = 8.0 * nh * nr ** 3
        apply = 8.0 * nh * nr ** 2 if self.Psolve is None else self.Psolve.apply_flops
        if self.lowrank is not None:
            sizes = np.array(self.lowrank.sizes, dtype=float)
            m = float(sizes.sum())
            build += 2.0 / 3.0 * float(np.sum(sizes ** 3)) + 2.0 * m * m * d / sizes.size
            apply = 2.0 * apply + 2.0 * float(np.sum(sizes ** 2)) + 2.0 * m * d
        if self.Binv is not None:
            build += 2.0 * ne * d ** 3
            apply += matvec + 2.0 * ne * d * d
        self.build_flops = build
        self.iteration_flops = apply + matvec + 4.0 * nz * 20

    def _shift(self, scale, i, u, ell):
        """``(sigma u, ell)`` of the shift of the ``i``-th harmonic, ``sigma`` making its
        largest entry about ``scale`` (zero where any of them is); sets ``self.C2``."""
        jac, self.shift_scale = self.jac, scale
        u, ell = np.asarray(u, dtype=complex), np.asarray(ell, dtype=complex)
        un, ln = float(np.linalg.norm(u)), float(np.linalg.norm(ell))
        if un == 0.0 or ln == 0.0 or scale == 0.0:
            return np.zeros_like(u), ell
        su = (scale / (un * ln)) * u
        C2 = np.zeros((jac.n_c, jac.n_r, 2))
        for k, y in enumerate((su, 1j * su)):      # embed(y): cos rows Re y, sin rows -Im y
            C2[jac._ic[i], :, k] = y.real
            if not jac._h0[i]:
                C2[jac._is[i], :, k] = -y.imag
        self.C2 = C2.reshape(jac.n_z, 2)
        return su, ell

    def _selection(self) -> "RowBlocks | None":
        """The row blocks of the low-rank stage with ``P`` holding ``self.proj``
        (:meth:`_lowrank`); None without elements."""
        jac = self.jac
        nc = jac.n_c
        rows, nb, Tk = element_tangent(self.jac)
        ne = Tk.shape[0]
        if ne == 0:
            return None
        ref = max(float(np.abs(Tk).max(initial=0.0)), 1e-300)   # the largest tangent entry
        Lk = Tk                         # (made in place: ref is taken before)
        # subtract the harmonic projection that P already holds
        pairs = []
        if jac.Juu is not None:
            pairs.append((0, 0, "uu", 1.0))
            if jac.Jug is not None and nb == 2:
                pairs.append((0, 1, "ug", 1.0))
        if jac.JNN is not None:
            pairs.append((nb - 1, nb - 1, "NN", -1.0))
        for a, b, key, sgn in pairs:
            for i, h in enumerate(jac.basis.harmonics):
                ic, is_ = jac._ic[i], jac._is[i]
                p = sgn * self.proj[key][i]
                Lk[:, a * nc + ic, b * nc + ic] -= p.real
                if h:
                    Lk[:, a * nc + ic, b * nc + is_] -= p.imag
                    Lk[:, a * nc + is_, b * nc + ic] += p.imag
                    Lk[:, a * nc + is_, b * nc + is_] -= p.real
        d = nb * nc
        Lb = Lk.reshape(ne, nb, nc, d)                        # row blocks (element, kind)
        norm = np.sqrt(np.einsum("ebij,ebij->eb", Lb, Lb)).ravel()
        # below LOWRANK_NEGLIGIBLE of the largest tangent entry the correction is
        # round-off of the AFT (or changes GMRES by an iteration at most)
        sel = np.flatnonzero(norm > LOWRANK_NEGLIGIBLE * ref)  # index e nb + kind

        limit = jac.cache.lowrank_max          # LOWRANK_MAX, or raised by the cache

        def blocks(fraction):           # row blocks in a correction of that many coordinates
            return int(min(max(fraction * jac.n_z, LOWRANK_MIN), limit)) // nc
        # a raised limit truncates to itself, not to LOWRANK_MAX_FRACTION
        most = sel.size if sel.size <= blocks(LOWRANK_EXACT_FRACTION) else \
            blocks(LOWRANK_EXACT_FRACTION if limit > LOWRANK_MAX else LOWRANK_MAX_FRACTION)
        if self.loose and sel.size * nc > LOOSE_SPLIT_MIN and (
                jac.cache.single_solve or most < sel.size
                or sel.size * nc > LOOSE_SPLIT_SHARED_MIN):
            # a loose solve, one per preconditioner, large or else truncated: every row
            # block, I + L_r G by element blocks (solve_capacitance)
            return RowBlocks(rows, nb, Lb, norm, sel, sel.size, True)
        return RowBlocks(rows, nb, Lb, norm, sel, most, False)

    def _lowrank(self):
        """Exact correction for the elements whose tangent couples harmonics.

        The preconditioner ``P`` holds ``S_h`` and the harmonic-``h`` projection of
        every element's tangent, so ``J = P + L`` with ``L`` the rest of the element
        tangents: block-diagonal over elements and zero for an element that sticks
        (and stays closed) over the whole period.  (A partial preconditioner's ``P`` is
        its base's, so ``L`` is the tangent minus the base's projection: zero for the
        elements that stuck in both states.)  ``L`` is kept by *row blocks*: the
        slip rows or the gap rows of one element over all coefficients (``n_c``
        coordinates each), and only the blocks where it is not negligible.  An
        element that slips but stays closed has a constant normal tangent, so only
        its slip rows count (measured on 96 Gauss points at force scale 20: 66
        elements slip, 26 of them separate, 92 row blocks instead of 132).  With
        ``E_r`` the selected rows, ``E_c`` all coordinates of their elements and
        ``L_r`` (``m`` x ``m_c``) those rows of ``L``, ``J = P + E_r L_r E_c^T`` and
        Woodbury's identity gives ``J^-1 b = y - P^-1 E_r s`` with ``y = P^-1 b`` and
        ``(I + L_r G) s = L_r y_c``, ``G = E_c^T P^-1 E_r`` (``m_c`` x ``m``): per
        harmonic only the (columns' rows, selected rows) part of ``P_h^-1`` is needed.
        The LU is of size ``m`` (``m^3``: a third of the cost of the element-wise
        correction at that point).  When ``m`` would exceed ``LOWRANK_EXACT_FRACTION
        n_z`` (but at least ``LOWRANK_MIN``) or ``LOWRANK_MAX``, only the row blocks
        with the largest ``|L|`` are kept, ``LOWRANK_MAX_FRACTION n_z`` coordinates
        (``self.truncated``; GMRES and the element-block stage handle the rest).  A large
        loose correction (an FRC point's extended solve, an EPMC point's extended Newton
        steps) keeps every row block instead and is split: no LU, ``I + L_r G`` kept by
        its element blocks as the preconditioner of its capacitance system
        (``LOOSE_SPLIT_MIN``, :func:`.lowrank_stage.capacitance_element_blocks`,
        :meth:`solve_capacitance`); as a preconditioner of ``J`` it applies those blocks
        in place of the inverse.
        """
        jac = self.jac
        nc = jac.n_c
        got = self._sel[1] if self._sel is not None and self._sel[0] is self.proj \
            else self._selection()
        self._sel = None
        if got is None:
            self.truncated = False
            return
        rows, nb, Lb, norm, sel, most, split = got
        self.truncated, kept = sel.size > most, min(most, sel.size)
        log.debug("low-rank stage: %d of %d coordinates wanted, %d kept", sel.size * nc,
                  jac.n_z, kept * nc)
        if self.truncated and self.modal and not self.partial:
            # the stuck stiffness is far from this tangent: a truncated correction
            # serves better on the harmonic projections of the tangent
            self._harmonic_stage(self._shift, modal=False)
            return self._lowrank()
        if self.truncated:
            sel = np.sort(sel[np.argsort(norm[sel])[::-1][:most]])
        if sel.size == 0:
            return
        el, kind = np.divmod(sel, nb)                         # element and kind of each block
        elems, blk_el = np.unique(el, return_inverse=True)    # the column elements
        nrb = sel.size
        R = np.concatenate([r[elems] for r in rows])          # columns' rows, index b nl + l
        Rrow = np.array([rows[k][e] for e, k in zip(el, kind)], dtype=np.intp)
        m = nrb * nc
        # The column coordinates are ordered element-major, (l d + b n_c + k), the
        # selected ones block-major, (j n_c + k), so that L_r is one (n_c, d) block per
        # row block and nothing is permuted.
        Lr = np.ascontiguousarray(Lb[el, kind])               # (nrb, n_c, d)
        Lr4 = Lr.reshape(nrb, nc, nb, nc)
        # the selected columns of P_h^-1: the correction P^-1 E_r s lives on the Rrow
        # rows; G is their R rows.  From the compressed flexibility, only those rows
        # are read when the columns are many, and the correction is a solve
        self.PinvR_double = {}
        if isinstance(self.Psolve, FlexibilitySolve) and nrb > SOLVED_STAGE_COLUMNS * jac.n_r:
            self.PinvR, PR, R_PR = None, self.Psolve.columns(Rrow, R), np.arange(R.size)
            PR[jac._h0] = PR[jac._h0].real             # (R_PR: R's rows in PR)
        else:       # (the correction's columns in the stage's precision)
            self.PinvR = PR = self._inverse_columns(Rrow)
            R_PR = R
            if self.Pinv is not None and self.Pinv.dtype == np.complex64 and self.Pinv_double:
                self.PinvR = PR.astype(np.complex64)
                self.PinvR_double = {i: PR[i].copy() for i in self.Pinv_double}
        single = self.loose or m >= SINGLE_LU_MIN                  # the LU in float32
        dtype = np.float32 if single else float
        if not split:
            C = capacitance_blocks(jac, PR, Lr4, R_PR, blk_el, dtype)
            C[np.diag_indices_from(C)] += 1.0
            self.lowrank = LowRankStage(R, Rrow, blk_el, Lr, nb,
                                        lu=sla.lu_factor(C, check_finite=False))
            return
        # split: I + L_r G by element blocks and a coarse space, G by harmonics (solve_capacitance)
        self.lowrank = LowRankStage(
            R, Rrow, blk_el, Lr, nb,
            blocks=capacitance_element_blocks(jac, PR, Lr4, R_PR, blk_el, dtype),
            Q=(PR if self.PinvR is None else PR[:, R_PR]).astype(np.complex64),
            Q_double={i: PR[i][R_PR] for i in self._double_harmonics()},
            coarse=capacitance_coarse(jac, PR, Lr4, R_PR, blk_el, Rrow, kind))

    def _harmonic_solve(self, V):
        """``P^-1`` of the harmonic stage; ``V`` (n_c, n_r, k) real, returns its shape."""
        out = np.empty_like(V)
        self.jac._from_complex(self._inverse_times(self.jac._to_complex(V)), out)
        return out

    def _element_blocks(self):
        """Inverse of each element's own block of ``J`` (its slip and gap rows over all
        coefficients, contact tangent with its harmonic coupling plus the diagonal of
        ``S_h``): the second stage of the preconditioner."""
        jac = self.jac
        nc = jac.n_c
        rows, nb, Bk = element_tangent(self.jac)
        for a, ra in enumerate(rows):
            for b, rb in enumerate(rows):
                Se = schur_entries(self.Psolve.prod, ra, rb) if self.S is None else None
                for i, h in enumerate(jac.basis.harmonics):
                    S = self.S[i][ra, rb] if Se is None else Se[i]
                    ic, is_ = jac._ic[i], jac._is[i]
                    Bk[:, a * nc + ic, b * nc + ic] += S.real
                    if h:
                        Bk[:, a * nc + ic, b * nc + is_] += S.imag
                        Bk[:, a * nc + is_, b * nc + ic] -= S.imag
                        Bk[:, a * nc + is_, b * nc + is_] += S.real
        self.rows = np.concatenate(rows)
        self.nb = nb
        self.Binv = np.linalg.inv(Bk)

    def apply(self, v, jac) -> np.ndarray:
        """The preconditioner of the scaled ``jac = J diag(col)``: ``diag(col)^-1 P^-1 v``
        (two-stage when ``TWO_STAGE``); ``v`` of shape (n_z,) or (n_z, k)."""
        v = np.asarray(v, dtype=float)
        V = v.reshape(jac.n_z, -1)
        col = jac.col[:, None]
        X = self.solve(V) if self.Binv is None else \
            self.solve2(V, lambda x: jac.matvec(x / col))
        return (X / col).reshape(v.shape)

    def solve2(self, v, matvec) -> np.ndarray:
        """Two-stage: ``x = P^-1 v``, then ``x += B^-1 (v - J x)`` (element blocks);
        ``v`` of shape (n_z,) or (n_z, k), every column at once (one low-rank
        solve and one product with ``J`` for the k columns)."""
        jac = self.jac
        nc, ne, nb = jac.n_c, len(jac.t_row), self.nb
        V = np.asarray(v, dtype=float).reshape(jac.n_z, -1)
        k = V.shape[1]
        x = self.solve(V)
        r = (V - matvec(x)).reshape(nc, jac.n_r, k)
        # each element's slip and gap rows over all coefficients, (ne, nb n_c, k)
        rb = r[:, self.rows].transpose(1, 0, 2).reshape(nb, ne, nc, k) \
            .transpose(1, 0, 2, 3).reshape(ne, nb * nc, k)
        d = np.matmul(self.Binv, rb)
        d = d.reshape(ne, nb, nc, k).transpose(2, 1, 0, 3).reshape(nc, nb * ne, k)
        X = x.reshape(nc, jac.n_r, k).copy()
        X[:, self.rows] += d
        return X.reshape(np.shape(v))

    def solve(self, v) -> np.ndarray:
        """``P^-1 v`` for the unscaled ``J``; ``v`` of shape (n_z,) or (n_z, k)."""
        jac = self.jac
        v = np.asarray(v, dtype=float)
        V = v.reshape(jac.n_c, jac.n_r, -1)
        Y = self._harmonic_solve(V)
        if self.lowrank is None:
            return Y.reshape(v.shape)
        lr = self.lowrank
        k = V.shape[2]
        rhs = np.matmul(lr.Lr, self._column_coordinates(Y[:, lr.R])[lr.block_element])
        s = lr.capacitance_inverse(rhs.reshape(-1, k))
        return (Y - self._correction(s)).reshape(v.shape)

    def _column_coordinates(self, Yr) -> np.ndarray:
        """The column elements' coordinates ``Yr`` (n_c, R.size, k), the ``R`` rows of
        coefficient rows, in the low-rank stage's element-major order (l, b n_c + c):
        shape (n_l, nb n_c, k)."""
        lr = self.lowrank
        nc, k = self.jac.n_c, Yr.shape[2]
        nl = lr.R.size // lr.nb
        return Yr.reshape(nc, lr.nb, nl, k).transpose(2, 1, 0, 3).reshape(nl, -1, k)

    def _amplitudes(self, s) -> np.ndarray:
        """The complex amplitudes (n_h, nrb, k) of the low-rank coordinates ``s`` (m, k),
        index ``j n_c + c``."""
        nc, k = self.jac.n_c, s.shape[1]
        return self.jac._to_complex(np.ascontiguousarray(
            s.reshape(-1, nc, k).transpose(1, 0, 2)))

    def _correction(self, s) -> np.ndarray:
        """``P^-1 E_r s`` (n_c, n_r, k) for ``s`` (m, k): only the ``Rrow`` columns of
        ``P_h^-1`` (n_r x nrb per harmonic, not n_r x n_r: the same nonzero terms, a
        fraction of the memory traffic), or the stage's solve without them."""
        jac = self.jac
        out = np.empty((jac.n_c, jac.n_r, s.shape[1]))
        A = self._amplitudes(s)
        if self.PinvR is None:           # the stage's solve on the Rrow coordinates
            E = np.zeros((A.shape[0], jac.n_r, A.shape[2]), dtype=complex)
            E[:, self.lowrank.Rrow] = A
            jac._from_complex(self._inverse_times(E), out)
        else:
            jac._from_complex(mixed_times(self.PinvR, self.PinvR_double, A), out)
        return out

    @property
    def capacitance_solves(self) -> bool:
        """Whether :meth:`solve_capacitance` applies: a split low-rank stage (``I + L_r G``
        by element blocks), not truncated (with a shift it solves ``J + C2 R2``)."""
        return self.lowrank is not None and self.lowrank.split \
            and self.Binv is None

    def solve_capacitance(self, b, rtol: float):
        """``J^-1 b`` for the unscaled ``J`` (``(J + C2 R2)^-1 b`` with a shift), by GMRES on
        the low-rank stage's capacitance system (:attr:`capacitance_solves`; the error
        indicators' extended solves).

        Woodbury: ``x = y - P^-1 E_r s``, ``y = P^-1 b``, ``(I + L_r G) s = L_r E_c^T y``.
        Then ``J x - b = -E_r ((I + L_r G) s - L_r E_c^T y)``: the capacitance system's
        residual is the whole system's, so GMRES on its ``m`` unknowns, preconditioned
        by its element blocks and coarse space (:attr:`LowRankStage.blocks`, ``coarse``),
        stops at ``rtol |b|``.  A product with ``I + L_r G`` reads ``G`` by harmonics
        (:attr:`LowRankStage.Q`) and ``L_r`` by row blocks, not the ``S_h`` and the
        harmonic stage: measured at 240-point gross-slip points (three columns), 7 ms an
        iteration against 27 ms on ``J`` preconditioned by the same split, and about as
        many iterations (round 34).  ``P^-1`` and ``G`` are in single precision, so the
        result is refined on ``J`` itself
        (:func:`~jointsim.solvers.jacobian.krylov_solve`).

        Parameters
        ----------
        b : ndarray, shape (n_z,) or (n_z, k)
        rtol : float
            Relative residual ``|J x - b| / |b|`` per column.

        Returns
        -------
        x : ndarray, shape of ``b``
        iterations : int
            GMRES iterations, summed over the columns.
        """
        jac, lr = self.jac, self.lowrank
        nc = jac.n_c
        B = np.asarray(b, dtype=float).reshape(jac.n_z, -1)
        k = B.shape[1]
        Y = self._harmonic_solve(B.reshape(nc, jac.n_r, k))
        rhs = np.matmul(lr.Lr, self._column_coordinates(Y[:, lr.R])[lr.block_element]) \
            .reshape(-1, k)

        def product(S):
            T = np.empty((nc, lr.R.size, S.shape[1]))
            A = self._amplitudes(S)
            jac._from_complex(mixed_times(lr.Q, lr.Q_double, A), T)            # G s
            return S + np.matmul(lr.Lr, self._column_coordinates(T)[lr.block_element]) \
                .reshape(S.shape)

        bn, rn = np.linalg.norm(B, axis=0), np.linalg.norm(rhs, axis=0)
        pos = rn > 0.0
        tol = rtol * float(np.min(bn[pos] / rn[pos])) if pos.any() else rtol
        cols = gmres_columns(product, rhs, lr.capacitance_inverse, rtol=tol)
        s = np.column_stack([c.x for c in cols])
        return (Y - self._correction(s)).reshape(np.shape(b)), sum(c.iterations for c in cols)
