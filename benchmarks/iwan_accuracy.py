"""Iwan accuracy against cost: equal-width bins (40 sliders) against the default
geometric bins sized for a 1 % dissipation error.

For each slider-density exponent chi, prints the slider count, the largest
relative error of the dissipation per cycle against Segalman's closed form
from 0.01 phi_max to phi_max (:func:`jointsim.contact.laws.iwan4_dissipation_error`),
and the time per element of an AFT evaluation (harmonics 0..7, 128 samples,
200 elements, fixed normal load, serial kernels), both discretisations timed side by side in
one run, with their ratio.

Run from the repository root: ``python -m benchmarks.iwan_accuracy``.
"""
import time

import numpy as np
import scipy.sparse as sp

from jointsim.blas import limit_blas_threads
from jointsim.contact import GivenNormal
from jointsim.contact.laws import iwan4_dissipation_error
from jointsim.contact.select import tangential_law
from jointsim.harmonics import HarmonicBasis
from jointsim.model import ContactSet
from jointsim.scene import Joint
from jointsim.solvers.aft import AFT


def aft_time(law, repeats=5):
    """Median wall time of one AFT evaluation per element [s]."""
    ne = law.n_elements
    eye = sp.identity(ne, format="csr")
    cs = ContactSet(eye, eye, np.zeros(ne), np.full(ne, 5.0), np.ones(ne), law,
                    GivenNormal(np.ones(ne)), np.zeros((ne, 2)))
    basis = HarmonicBasis(range(8), 128)
    aft = AFT(cs, basis, parallel=False)   # the cost of the work, not of thread start-up
    U = np.random.default_rng(0).normal(size=(basis.n_coeff, ne)) * 0.3
    aft.evaluate(U)                      # compile / warm up
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        aft.evaluate(U)
        times.append(time.perf_counter() - t0)
    return float(np.median(times)) / ne


def main():
    limit_blas_threads()
    print(f"{'chi':>5} {'uniform n':>9} {'error':>8} {'us/elem':>8} | {'default n':>9} "
          f"{'error':>8} {'us/elem':>8} | {'time ratio':>10}")
    for chi in (-0.9, -0.5, -0.2, 0.3):
        j_uni = Joint(law="iwan4", mu=0.1, kt=2.0, chi=chi, beta=0.2, n_sliders=40,
                      iwan_spacing="uniform")
        j_geo = Joint(law="iwan4", mu=0.1, kt=2.0, chi=chi, beta=0.2)
        uni = tangential_law("iwan4", "anchor", j_uni, np.ones(200))
        geo = tangential_law("iwan4", "anchor", j_geo, np.ones(200))
        e_uni = iwan4_dissipation_error(chi, 40, "uniform")
        e_geo = iwan4_dissipation_error(chi, geo.n_sliders, "geometric",
                                        *_lowest(chi, geo.n_sliders))
        t_uni, t_geo = aft_time(uni), aft_time(geo)
        print(f"{chi:>5.1f} {uni.n_sliders:>9d} {e_uni:>8.3f} {1e6 * t_uni:>8.2f} | "
              f"{geo.n_sliders:>9d} {e_geo:>8.4f} {1e6 * t_geo:>8.2f} | {t_geo / t_uni:>10.2f}")


def _lowest(chi, n):
    from jointsim.contact.laws import iwan4_design
    return (iwan4_design(chi, 0.01, n=n)[1],)


if __name__ == "__main__":
    main()
