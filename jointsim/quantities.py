"""The quantities a run produces, and their errors against a reference.

What ``jointsim converge`` and the presets compare (issue 12): FRC peak
amplitudes and frequencies, EPMC and QSMA frequency and damping at the loop
amplitudes (the EPMC's exact solutions there when the file has them), the
transient's steady harmonics or free-decay backbone, and the area-weighted
shares of loop sets on the manifold and on classical Masing.  One list per
scene, in a fixed order, so that two files of the same scene at other
settings compare item by item.
"""
from __future__ import annotations

from dataclasses import dataclass

import h5py
import numpy as np


@dataclass(frozen=True)
class Quantity:
    """A number a run produces, how its error is measured, and its unit."""

    name: str
    value: float
    unit: str
    absolute: bool = False  # fractions: absolute error


def _amplitudes(scene, section) -> np.ndarray:
    """Modal amplitudes where backbones are compared [sqrt(kg) m]: the scene's loop
    amplitudes (or solved amplitudes), else four inside its range."""
    amps = tuple(section.loop_amplitudes) if hasattr(section, "loop_amplitudes") else ()
    amps = amps or tuple(getattr(section, "amplitudes", ()))
    if amps:
        return np.asarray(amps, dtype=float)
    lo, hi = section.log10_amplitude_start, section.log10_amplitude_end
    return 10.0 ** np.linspace(lo + 0.15 * (hi - lo), hi - 0.15 * (hi - lo), 4)


def _set_labels(h5, prefix: str, point) -> list[tuple[int, str]]:
    """``(index, name)`` of the loop sets of ``prefix`` in a fixed order.

    FRC branches run on worker processes and store their peak loops in the
    order they finish, so an FRC set is named by its branch's force scale (and
    its rank on that branch), not by its row; other sets by their row.
    """
    name = prefix or "loops"
    if prefix.endswith("at_amplitudes"):          # exact EPMC sets: named by amplitude
        amp = h5[f"{prefix}/amplitude"][()][point]
        return [(k, f"epmc loops at a = {amp[k]:.3g}") for k in range(len(point))]
    if prefix != "hbm" or "hbm/branch" not in h5 or "hbm/force_scale" not in h5:
        return [(k, f"{name} set {k}") for k in range(len(point))]
    fs = h5["hbm/force_scale"][()][h5["hbm/branch"][()][point]]   # per branch, per point
    order = sorted(range(len(point)), key=lambda k: (fs[k], point[k]))
    out, rank = [], {}
    for k in order:
        j = rank[fs[k]] = rank.get(fs[k], -1) + 1
        out.append((k, f"hbm loops {j} at force x {fs[k]:g}"))
    return out


def quantities(path, scene) -> list[Quantity]:
    """The quantities of one result file, in a fixed order for a given scene.

    Parameters
    ----------
    path : str or Path
        A complete result file of ``scene`` (at any setting of the dials).
    scene : jointsim.scene.Scene
        The user's scene (its sections and amplitudes fix the list).

    Returns
    -------
    list of Quantity
        NaN for a value the run did not reach (a branch that stopped early).
    """
    from .post.study import (_interp_log, exact_loop_group, exact_where_solved,
                             fraction_weights, loop_groups, loop_points, weighted_fractions)
    out: list[Quantity] = []
    a = scene.analysis
    hz = "Hz" if scene.model.units == "SI" else "1/time"
    with h5py.File(path, "r") as h5:
        if a.hbm is not None:
            g = h5["hbm"]
            pa = g["peak_amplitude"][()] if "peak_amplitude" in g else np.array([])
            po = g["peak_omega"][()] if "peak_omega" in g else np.array([])
            for b, fs in enumerate(a.hbm.force_scale):
                amp = float(pa[b]) if b < pa.size else np.nan
                om = float(po[b]) if b < po.size else np.nan
                out.append(Quantity(f"FRC peak amplitude, force x {fs:g}", amp,
                                    "m" if scene.model.units == "SI" else "length"))
                out.append(Quantity(f"FRC peak frequency, force x {fs:g}",
                                    om / (2 * np.pi), hz))
        for name, label in (("epmc", "EPMC"), ("qsma", "QSMA")):
            sec = getattr(a, name, None)
            if sec is None:
                continue
            amps = _amplitudes(scene, a.epmc if name == "qsma" and a.epmc is not None
                               else sec)
            g = h5[name] if name in h5 else None
            for key, what, u in (("frequency_hz", "frequency", hz),
                                 ("damping_ratio", "damping", "1")):
                vals = (_interp_log(amps, g["amplitude"][()], g[key][()])
                        if g is not None and key in g else np.full(amps.shape, np.nan))
                if name == "epmc" and g is not None and "at_amplitudes" in g:
                    vals = exact_where_solved(g["at_amplitudes"], amps, key, vals)
                for am, v in zip(amps, vals):
                    out.append(Quantity(f"{label} {what} at a = {am:.3g}", float(v), u))
        tr = getattr(a, "transient", None)
        if tr is not None:
            g = h5["transient"] if "transient" in h5 else None
            if tr.omega > 0:
                X = g["harmonics"][()] if g is not None and "harmonics" in g else None
                v = float(np.linalg.norm(X)) if X is not None else np.nan
                out.append(Quantity("transient steady harmonics (norm)", v,
                                    "m" if scene.model.units == "SI" else "length"))
            else:
                amps = 10.0 ** np.linspace(np.log10(tr.amplitude) - 1.0,
                                           np.log10(tr.amplitude) - 0.2, 3)
                for key, what, u in (("frequency_hz", "frequency", hz),
                                     ("damping_ratio", "damping", "1")):
                    vals = (_interp_log(amps, g["amplitude"][()], g[key][()])
                            if g is not None and key in g else np.full(3, np.nan))
                    for am, v in zip(amps, vals):
                        out.append(Quantity(f"free decay {what} at a = {am:.3g}",
                                            float(v), u))
        for prefix in loop_groups(h5):
            prefix = exact_loop_group(h5, prefix)
            sets = loop_points(h5, prefix)
            w = fraction_weights(h5, sets.loaded.shape[1]).get(
                "area", np.ones(sets.loaded.shape[1]))
            man, mas, _ = weighted_fractions(sets, w)
            for k, label in _set_labels(h5, prefix, sets.point):
                out.append(Quantity(f"{label}: on-manifold share", float(man[k]), "1",
                                    absolute=True))
                out.append(Quantity(f"{label}: on-Masing share", float(mas[k]), "1",
                                    absolute=True))
    return out


def errors(q: list[Quantity], ref: list[Quantity]) -> np.ndarray:
    """Error of each quantity against the reference's of the same name.

    Relative ``|q - q_ref| / |q_ref|`` (absolute for fractions); ``inf`` when
    a value is missing in ``q`` but not in the reference, ``NaN`` when the
    reference has none either.

    Returns
    -------
    ndarray, shape (len(ref),)
    """
    by_name = {x.name: x.value for x in q}
    out = np.empty(len(ref))
    for i, r in enumerate(ref):
        v = by_name.get(r.name, np.nan)
        if not np.isfinite(r.value):
            out[i] = np.nan
        elif not np.isfinite(v):
            out[i] = np.inf
        elif r.absolute:
            out[i] = abs(v - r.value)
        else:
            out[i] = abs(v - r.value) / abs(r.value) if r.value != 0 else abs(v)
    return out


# ---------------------------------------------------------------- the study

KINDS = (("frequency", "frequency"), ("damping", "damping"), ("amplitude", "amplitude"),
         ("share", "share"))


def kind_errors(names, err) -> dict[str, float]:
    """Largest error per kind of quantity (frequency, damping, amplitude, share).

    Parameters
    ----------
    names : list of str
        Quantity names (:func:`quantities`).
    err : ndarray, shape (len(names),)
        Their errors (NaN: no reference value; inf: not reached).

    Returns
    -------
    dict
        ``{kind: largest error}``, NaN for a kind without quantities.
    """
    out = {}
    err = np.asarray(err, dtype=float)
    for kind, word in KINDS:
        sel = np.array([word in n for n in names], bool)
        e = err[sel] if sel.size else np.zeros(0)
        e = e[~np.isnan(e)]
        out[kind] = float(e.max()) if e.size else np.nan
    return out
