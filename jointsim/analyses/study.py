"""The study's third column: the stored loops replayed through the manifold law.

After an analysis has stored element loops (``/<prefix>/loops``) and their
Masing checks (``/<prefix>/masing``), :func:`write_control` replays every
loop's kinematics ``(u(t), N(t))`` through the ``manifold`` reversal law and
the physical law (:func:`jointsim.masing.replay_control`) and writes
``/<prefix>/control``: the control for seed condition 5, and the attribution
of each physical loop (on its manifold; off it: condition 5, Eq. 4/Eq. 6, or
the control off too).  The manifold is the seed's Eq. 7 with its friction
limit (the Masing construction clipped to ``+-mu N``).
"""
from __future__ import annotations

import logging
from types import SimpleNamespace

import numpy as np

from ..io.hdf5 import unit
from ..masing import CAUSE_NAMES, replay_control

log = logging.getLogger(__name__)


def write_control(writer, prefix: str, law, tol: float, units: str) -> bool:
    """Replay the loops under ``prefix`` through the manifold law and write ``/<prefix>/control``.

    The whole group is rewritten (a resumed run replays every stored set).

    Parameters
    ----------
    writer : jointsim.io.hdf5.ResultWriter
    prefix : str
        The analysis group with loops (``epmc``, ``hbm``).
    law : jointsim.contact.TangentialLaw
        The physical law of the loops.
    tol : float
        On-manifold tolerance (``analysis.masing.tol``).
    units : str
        Unit system of the model.

    Returns
    -------
    bool
        False when there was nothing to replay (no loops, or a law that cannot slip).
    """
    h5 = writer.h5
    if f"{prefix}/loops/u" not in h5 or h5[f"{prefix}/loops/u"].shape[0] == 0:
        return False
    L, M = h5[f"{prefix}/loops"], h5[f"{prefix}/masing"]
    U, F, NN = L["u"][()], L["f"][()], L["N"][()]
    rows = []
    for i in range(U.shape[0]):
        phys = SimpleNamespace(on_manifold=M["on_manifold"][i], eq4_ok=M["eq4_ok"][i],
                               eq6_ok=M["eq6_ok"][i])
        r = replay_control(U[i], F[i], NN[i], law, phys, tol)
        if r is None:
            return False
        rows.append(r)
    g = f"{prefix}/control"
    one, Fu = "1", unit("force", units)
    # read as a whole (:func:`jointsim.post.study.control_sets`): all or nothing
    with writer.whole_group(g, law="bank_manifold", tol=float(tol),
                            doc="the loops' (u, N) replayed through the manifold reversal "
                                "law (seed condition 5 with Masing's memory rule) and the "
                                "physical law") as g:
        writer.write(f"{g}/f", np.stack([r.f for r in rows]), Fu,
                     "manifold-law force over the replayed steady period")
        writer.write(f"{g}/dev_manifold", np.stack([r.report.dev_manifold for r in rows]), one,
                     "max |f_control - f_manifold| / max(mu N), manifold clipped to +-mu N "
                     "(seed Eq. 7; round-off where the control loop closes)")
        writer.write(f"{g}/on_manifold", np.stack([r.report.on_manifold for r in rows]), one,
                     "control dev_manifold <= tol")
        writer.write(f"{g}/excess", np.stack([r.excess for r in rows]), one,
                     "max(|unclipped manifold construction| - mu N, 0) / max(mu N) of the "
                     "control loop: where > 0 the manifold follows +-mu N somewhere")
        writer.write(f"{g}/periodicity", np.stack([r.periodicity for r in rows]), one,
                     "control force change between the last two replayed periods / max(mu N)")
        writer.write(f"{g}/replay_error", np.stack([r.replay_error for r in rows]), one,
                     "max |f_physical replayed - f stored| / max(mu N)")
        writer.write(f"{g}/cause", np.stack([r.cause for r in rows]), one,
                     "attribution of the physical loop: " + "; ".join(
                         f"{k} = {name}" for k, name in enumerate(CAUSE_NAMES)),
                     names=list(CAUSE_NAMES))
    dev = np.stack([r.report.dev_manifold - r.periodicity for r in rows])
    log.info("%s control: %d loop sets replayed through the manifold law; control "
             "dev_manifold - non-periodicity <= %.2e", prefix, len(rows), float(dev.max()))
    return True
