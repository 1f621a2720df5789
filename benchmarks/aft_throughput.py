"""Cost of one AFT residual + Jacobian per contact element (issue 4).

Jenkins elements with coupled normal load (unilateral, separation on),
harmonics 0..7, 128 samples per period, random coefficients that make every
element stick, slip and separate during the period.  For 10, 100 and 1000
elements, times :meth:`jointsim.solvers.aft.AFT.evaluate` (numba kernels)
and the plain-NumPy implementation of ``tests/_aft_reference.py`` side by side in
the same run, and prints microseconds per element and their ratio.

Run from the repository root: ``python -m benchmarks.aft_throughput [--threads N]``.  Numba's
compilation is done (and timed separately) before the measurement.

``--laws`` (issue 14) instead times the AFT kernels of the reversal laws side by
side in one run on the same coefficients -- ``anchor`` (physical), ``scaled``
(seed Eq. 7) and ``manifold`` (Eq. 7 with Masing's memory rule, a stack of open
reversals), for the Jenkins and the Iwan element (``joint.law = iwan4`` with
``--sliders`` sliders) -- and prints microseconds per element and the ratio to
the anchor law.  The paths have 5 harmonics of similar size, so every element
has several reversals (inner loops) per period, and the gap coefficients make
the normal load vary and separate.
"""
import argparse
import time

import numpy as np
import scipy.sparse as sp

from jointsim.contact import AnchoredBank, UnilateralPenalty
from jointsim.model import ContactSet
from jointsim.harmonics import HarmonicBasis
from jointsim.solvers.aft import AFT
from tests._aft_reference import anchor_aft_numpy


def contact_set(ne):
    law = AnchoredBank( np.full((ne, 1), 1.0), np.full((ne, 1), 0.3),
                        np.full(ne, 0.3))
    eye = sp.identity(ne, format="csr")
    return ContactSet(eye, eye, np.full(ne, -0.5), np.ones(ne), np.ones(ne), law,
                      UnilateralPenalty(np.ones(ne)), np.zeros((ne, 2)))


def law_set(ne, reversal, n_sliders):
    """A coupled contact set of ``ne`` elements with the tangential law of
    ``joint.law = jenkins`` (``n_sliders = 1``) or ``iwan4`` and ``reversal``."""
    from jointsim.contact.select import tangential_law
    from jointsim.scene import Joint
    name = "jenkins" if n_sliders == 1 else "iwan4"
    joint = Joint(law=name, reversal=reversal, mu=0.3, kt=1.0, chi=-0.5, beta=0.2,
                  n_sliders=n_sliders if n_sliders > 1 else None, iwan_spacing="uniform")
    law = tangential_law(name, reversal, joint, np.ones(ne))
    eye = sp.identity(ne, format="csr")
    return ContactSet(eye, eye, np.full(ne, -0.5), np.ones(ne), np.ones(ne), law,
                      UnilateralPenalty(np.ones(ne)), np.zeros((ne, 2)))


def compare_laws(b, rng, repeat, n_sliders):
    """Time the AFT of the three reversal laws side by side (see the module docstring)."""
    laws = ("anchor", "scaled", "manifold")
    for ns in (1, n_sliders):
        label = "jenkins" if ns == 1 else f"iwan4 ({ns} sliders)"
        for rev in laws:   # compile / load the cache outside the timing
            for ne in (3, 70):
                AFT(law_set(ne, rev, ns), b).evaluate(np.zeros((b.n_coeff, ne)) + 0.1,
                                                       np.zeros((b.n_coeff, ne)) + 0.1)
        print(f"\n{label}: us per element (ratio to anchor), H = {max(b.harmonics)}, "
              f"Nt = {b.n_samples}")
        print(f"{'elements':>9} " + " ".join(f"{r:>18}" for r in laws)
              + f" {'periods (a/s/m)':>16} {'reversals':>10}")
        for ne in (10, 100, 1000):
            U = rng.normal(size=(b.n_coeff, ne)) * 0.5
            U[0] = 0.0
            G = rng.normal(size=(b.n_coeff, ne)) * 0.15
            times, periods = {}, {}
            # interleave the laws so that load changes hit all of them alike
            afts = {rev: AFT(law_set(ne, rev, ns), b) for rev in laws}
            for rev in laws:
                times[rev] = []
            for _ in range(3):
                for rev in laws:
                    times[rev].append(best_of(lambda: afts[rev].evaluate(U, G), repeat))
            for rev in laws:
                times[rev] = min(times[rev])
                periods[rev] = int(afts[rev].evaluate(U, G).periods.max())
            u = (b.Gam @ U).T
            du = np.sign(np.diff(np.concatenate([u, u[:, :1]], axis=1), axis=1))
            nrev = np.mean(np.sum(du != np.roll(du, 1, axis=1), axis=1))
            cells = " ".join(f"{1e6 * times[r] / ne:>9.2f} ({times[r] / times['anchor']:>5.2f}x)"
                             for r in laws)
            print(f"{ne:>9} {cells} {'/'.join(str(periods[r]) for r in laws):>16} {nrev:>10.1f}")


def best_of(fn, repeat, min_time=0.2):
    """Median time of single calls, over at least ``repeat`` calls and ``min_time``."""
    times, t_start = [], time.perf_counter()
    while len(times) < repeat or time.perf_counter() - t_start < min_time:
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return float(np.median(times))


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--threads", type=int, default=None, help="numba threads (default: all)")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--laws", action="store_true",
                    help="compare the reversal laws anchor / scaled / manifold instead")
    ap.add_argument("--sliders", type=int, default=40, help="Iwan sliders for --laws")
    args = ap.parse_args()
    import numba
    if args.threads:
        numba.set_num_threads(args.threads)
    b = HarmonicBasis(range(8), 128)
    rng = np.random.default_rng(0)
    if args.laws:
        compare_laws(b, rng, args.repeat, args.sliders)
        return
    t0 = time.perf_counter()
    aft = AFT(contact_set(70), b)
    aft.evaluate(rng.normal(size=(b.n_coeff, 70)), rng.normal(size=(b.n_coeff, 70)))
    aft = AFT(contact_set(3), b)
    aft.evaluate(rng.normal(size=(b.n_coeff, 3)), rng.normal(size=(b.n_coeff, 3)))
    print(f"numba compile/cache load: {time.perf_counter() - t0:.2f} s; "
          f"threads: {numba.get_num_threads()}")
    print(f"{'elements':>9} {'numba us/elem':>14} {'numpy us/elem':>14} {'ratio':>7} "
          f"{'periods':>8} {'slip/sep':>9}")
    for ne in (10, 100, 1000):
        cs = contact_set(ne)
        aft = AFT(cs, b)
        U = rng.normal(size=(b.n_coeff, ne)) * 0.5
        G = rng.normal(size=(b.n_coeff, ne)) * 0.3
        r = aft.evaluate(U, G)
        frac_slip = np.mean(np.isclose(np.abs(r.f), 0.3 * r.N) & (r.N > 0))
        frac_sep = np.mean(r.N == 0.0)
        t_nb = best_of(lambda: aft.evaluate(U, G), args.repeat)
        k, g = cs.law.k, cs.law.g
        t_np = best_of(lambda: anchor_aft_numpy(U, G, cs.gap0, cs.kn, k, g, cs.N0, b, True),
                       max(1, args.repeat - 1), min_time=0.05)
        print(f"{ne:>9} {1e6 * t_nb / ne:>14.2f} {1e6 * t_np / ne:>14.1f} "
              f"{t_np / t_nb:>7.0f} {int(r.periods.max()):>8} "
              f"{frac_slip:>4.2f}/{frac_sep:.2f}")


if __name__ == "__main__":
    from jointsim.blas import limit_blas_threads
    limit_blas_threads()
    main()
