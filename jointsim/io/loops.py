"""The element loops and Masing checks of a solution point in a result file
(moved out of :mod:`jointsim.io.hdf5`, which re-exports :func:`write_loops`)."""
from __future__ import annotations

import h5py
import numpy as np

from .hdf5 import ResultWriter, unit


def write_loops(writer: ResultWriter, point: int, u, f, N, report, units: str,
                prefix: str) -> None:
    """Append one solution point's element loops and their Masing check.

    Every analysis keeps its loops under its own group (``/<prefix>/loops``,
    ``/<prefix>/masing``).  The root ``/loops`` and ``/masing`` of the public
    contract are soft links to the first analysis that wrote loops in the
    file, so a file with one loop-producing analysis reads as before.

    Parameters
    ----------
    writer : ResultWriter
    point : int
        Index of the solution point the loops belong to.
    u, f, N : ndarray, shape (n_e, n_samples)
        Steady period of each element.
    report : jointsim.masing.MasingReport
    units : str
        Unit system of the model.
    prefix : str
        The analysis group (``prescribed``, ``hbm``, ``epmc``, ``transient``).
    """
    p = prefix.strip("/") + "/" if prefix.strip("/") else ""
    # a file resumed from before the excess existed keeps its rows aligned without it
    with_excess = (f"{p}masing/dev_manifold" not in writer.h5
                   or f"{p}masing/manifold_excess" in writer.h5)
    with writer.commit():  # the loops and checks of a point: all or nothing
        d, F = unit("displacement", units), unit("force", units)
        writer.append(f"{p}loops/point", np.int64(point), "1", "solution point of each loop set")
        writer.append(f"{p}loops/u", u, d, "tangential displacement over one steady period")
        writer.append(f"{p}loops/f", f, F, "tangential force over one steady period")
        writer.append(f"{p}loops/N", N, F, "normal load over one steady period")
        one = "1"
        writer.append(f"{p}masing/dev_manifold", report.dev_manifold, one,
                      "max |f - f_manifold| / max(mu N)")
        writer.append(f"{p}masing/dev_masing", report.dev_masing, one,
                      "max |f - f_masing| / max(mu N), classical Masing at the mean N")
        writer.append(f"{p}masing/on_manifold", report.on_manifold, one, "dev_manifold <= tol")
        writer.append(f"{p}masing/on_masing", report.on_masing, one, "dev_masing <= tol")
        writer.append(f"{p}masing/eq4_ok", report.eq4_ok, one, "seed Eq. 4: d(mu N)/ds >= -kt "
                      "while the force opposes the motion after a reversal")
        writer.append(f"{p}masing/eq6_ok", report.eq6_ok, one, "seed Eq. 6: d(mu N)/ds <= kt "
                      "while slipping")
        writer.append(f"{p}masing/eq4_margin", report.eq4_margin, one, "held: min(1 + d(mu N)/ds / kt); violated: -integrated violation / (kt ptp(u))")
        writer.append(f"{p}masing/eq6_margin", report.eq6_margin, one, "held: min(1 - d(mu N)/ds / kt); violated: -integrated violation / (kt ptp(u))")
        writer.append(f"{p}masing/n_reversals", report.n_reversals, one, "reversals of u per period")
        writer.append(f"{p}masing/f_manifold", report.f_manifold, F,
                      "manifold prediction, clipped to +-mu N")
        writer.append(f"{p}masing/f_masing", report.f_masing, F, "classical Masing prediction")
        if report.manifold_excess is not None and with_excess:
            writer.append(f"{p}masing/manifold_excess", report.manifold_excess, one,
                          "max (|unclipped manifold construction| - mu N)_+ / max(mu N); "
                          "f_manifold is clipped to +-mu N (seed Eq. 7, second case)")
            writer.append(f"{p}masing/masing_excess", report.masing_excess, one,
                          "the same for the (unclipped) classical Masing prediction")
        writer.h5[f"{p}masing"].attrs["tol"] = report.tol
        if p and "loops" not in writer.h5:
            writer.h5["loops"] = h5py.SoftLink(f"/{p}loops")
            writer.h5["masing"] = h5py.SoftLink(f"/{p}masing")
            writer.h5.attrs["loops_of"] = prefix.strip("/")
