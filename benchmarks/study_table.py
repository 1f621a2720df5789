"""The README's study table ("Results: do the elements ... stay on their Masing
manifolds?") regenerated from result files (not collected by pytest).

    python benchmarks/study_table.py [--label NAME] FILE [FILE ...]

One block of rows per file: at each amplitude where the EPMC kept its loops
(the branch points nearest ``analysis.epmc.loop_amplitudes``), the EPMC and
QSMA frequency and damping ratio (QSMA interpolated in log amplitude to the
same modal amplitude) with their relative differences, and the fractions of
loaded elements on their manifold and on their classical Masing curve, by count
and weighted by contact area.  Every number comes from :mod:`jointsim.post.study`
(the functions ``jointsim info`` uses), so rerunning this on new files after a
change of the Masing check gives the new fraction columns.  The harmonics and
AFT samples of each file's EPMC are printed with it, and the run's status (a
failed run's rows are marked).

The scene column is ``--label`` (one per file, in order) or the scene name
stored in the file.
"""
from __future__ import annotations

import argparse
import sys

import h5py
import numpy as np

from jointsim.post.study import (backbone_comparison, fraction_weights, loop_points,
                                 manifold_fractions, weighted_fractions)

HEAD = ("| scene | modal amplitude [sqrt(kg) m] | f EPMC [Hz] | f QSMA [Hz] | diff. | "
        "zeta EPMC | zeta QSMA | diff. | on manifold | on classical Masing | "
        "by area (manifold / Masing) |\n|---|---|---|---|---|---|---|---|---|---|---|")


def rows(path, label: str | None = None) -> list[str]:
    """Markdown rows of one result file (see the module docstring).

    Parameters
    ----------
    path : str or Path
        A result file with ``/epmc`` (with loops) and ``/qsma``.
    label : str, optional
        Scene column; default the file's scene name.

    Returns
    -------
    list of str
    """
    out = []
    with h5py.File(path, "r", locking=False) as h5:
        name = label or str(h5.attrs.get("scene_name", h5.attrs.get("scene_path", path)))
        sets = loop_points(h5, "epmc")
        amps = sets.parameter
        bb = backbone_comparison(h5, amps) if "qsma" in h5 else []
        man, mas, n = manifold_fractions(sets)
        w = fraction_weights(h5, sets.loaded.shape[1]).get("area",
                                                          np.ones(sets.loaded.shape[1]))
        wman, wmas, _ = weighted_fractions(sets, w)
        st = h5.attrs.get("status")
        failed = "" if st == "complete" else f" (run {st})"
        for i, a in enumerate(amps):
            k_man = int(np.sum(sets.on_manifold[i] & sets.loaded[i]))
            k_mas = int(np.sum(sets.on_masing[i] & sets.loaded[i]))
            if bb:
                r = bb[i]
                cols = (f"{r.f_epmc:.2f} | {r.f_qsma:.2f} | {100 * r.df_rel:+.2f} % | "
                        f"{100 * r.zeta_epmc:.3f} % | {100 * r.zeta_qsma:.3f} % | "
                        f"{100 * r.dzeta_rel:+.1f} %")
            else:
                cols = "- | - | - | - | - | -"
            out.append(f"| {name}{failed} | {a:.2e} | {cols} | {man[i]:.2f} ({k_man}/{n[i]}) | "
                       f"{mas[i]:.2f} ({k_mas}/{n[i]}) | {wman[i]:.2f} / {wmas[i]:.2f} |")
    return out


def settings(path) -> str:
    """The EPMC's harmonics and samples and the QSMA points of a result file."""
    with h5py.File(path, "r", locking=False) as h5:
        e = h5["epmc"]
        hs = e["harmonics"][()].tolist() if "harmonics" in e else []
        nt = e.attrs.get("n_samples", "?")
        q = h5["qsma/amplitude"].shape[0] if "qsma/amplitude" in h5 else "-"
        return (f"{path}: EPMC harmonics {hs[0]}..{hs[-1]} ({len(hs)}), Nt = {nt}; "
                f"QSMA points {q}; status {h5.attrs.get('status', '?')}")


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("files", nargs="+")
    p.add_argument("--label", action="append", default=[],
                   help="scene column of each file, in order")
    a = p.parse_args(argv)
    labels = a.label + [None] * (len(a.files) - len(a.label))
    print(HEAD)
    for f, lab in zip(a.files, labels):
        print("\n".join(rows(f, lab)))
    print()
    for f in a.files:
        print(settings(f))
    return 0


if __name__ == "__main__":
    sys.exit(main())
