"""Cost of one AFT residual + Jacobian per contact element (issue 4).

Jenkins elements with coupled normal load (unilateral, separation on),
harmonics 0..7, 128 samples per period, random coefficients that make every
element stick, slip and separate during the period.  For 10, 100 and 1000
elements, times :meth:`jointsim.solvers.aft.AFT.evaluate` (numba kernels)
and the plain-NumPy implementation of ``tests/_aft_reference.py`` side by side in
the same run, and prints microseconds per element and their ratio.

Run from the repository root: ``python -m benchmarks.aft_throughput [--threads N]``.  Numba's
compilation is done (and timed separately) before the measurement.
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
    args = ap.parse_args()
    import numba
    if args.threads:
        numba.set_num_threads(args.threads)
    b = HarmonicBasis(range(8), 128)
    rng = np.random.default_rng(0)
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
