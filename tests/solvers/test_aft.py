"""AFT evaluation (:mod:`jointsim.solvers.aft`): the threaded and serial kernels agree."""
import numpy as np
import pytest
import scipy.sparse as sp

from jointsim import _harmonic_kernels as HK
from jointsim.contact import _aft_kernels as AK
from jointsim.contact.normal import UnilateralPenalty
from jointsim.contact.select import tangential_law
from jointsim.harmonics import HarmonicBasis
from jointsim.model import ContactSet
from jointsim.scene import Joint
from jointsim.solvers.aft import AFT


@pytest.mark.parametrize("reversal", ["anchor", "scaled"])
def test_parallel_false_gives_the_same_numbers_on_one_thread(reversal, monkeypatch):
    """Above the kernels' threading threshold, ``parallel=False`` (worker processes)
    runs the serial variants and gives the same forces and Jacobians, bit for bit."""
    ne = AK.PARALLEL_MIN + 6
    joint = Joint(law="iwan4", reversal=reversal, mu=0.2, kt=3.0, chi=-0.4, beta=0.3,
                  n_sliders=4)
    law = tangential_law("iwan4", reversal, joint, np.linspace(0.5, 1.5, ne), friction=True)
    eye = sp.identity(ne, format="csr")
    cs = ContactSet(eye, eye, np.full(ne, -0.5), np.full(ne, 2.0), np.ones(ne), law,
                    UnilateralPenalty(np.full(ne, 4.0)), np.zeros((ne, 2)))
    basis = HarmonicBasis((0, 1, 2, 3), 32)
    rng = np.random.default_rng(7)
    U = rng.normal(size=(basis.n_coeff, ne)) * 0.5
    G = rng.normal(size=(basis.n_coeff, ne)) * 0.15
    # a case this small runs on one thread anyway (work thresholds): lower them
    monkeypatch.setattr(AK, "PARALLEL_MIN_WORK", 0)
    monkeypatch.setattr(HK, "PARALLEL_MIN_WORK", 0)
    threaded = AFT(cs, basis).evaluate(U, G)

    def threads(*args):
        raise AssertionError("a threaded kernel ran with parallel=False")

    for mod, name in ((AK, "_anchor_parallel"), (AK, "_scaled_parallel"),
                      (HK, "_diag_parallel")):
        monkeypatch.setattr(mod, name, threads)
    serial = AFT(cs, basis, parallel=False).evaluate(U, G)
    for name in ("Ft", "Nc", "Juu", "Jug", "JNN", "f", "periods", "change"):
        assert np.array_equal(getattr(threaded, name), getattr(serial, name)), name
    # both drivers call the element kernels with an int64 index: one compiled signature
    # each (prange's own index is uint64, and a second signature costs up to 15 s of
    # compilation).  Seen where the kernels are compiled, not loaded from numba's cache
    # (a cached driver does not call its kernels' dispatchers: no signatures then): in
    # a fresh clone (CI) or with an empty NUMBA_CACHE_DIR.
    one = AK._anchor_one if reversal == "anchor" else AK._scaled_one
    for kernel in (one, HK._diag_one):
        assert all(str(sig[0]) == "int64" for sig in kernel.signatures), kernel.signatures
