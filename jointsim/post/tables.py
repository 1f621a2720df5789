"""Text tables of result files (``jointsim info``)."""
from __future__ import annotations

from pathlib import Path


from ..io.hdf5 import open_result


def _fmt_bool(b) -> str:
    return "yes" if bool(b) else "NO"


def masing_table(h5, point: int = -1, max_rows: int = 40) -> str:
    """Per-element Masing table at one solution point."""
    m = h5["masing"]
    n_points, ne = m["dev_manifold"].shape
    if n_points == 0:
        return "(no loops stored)"
    p = point if point >= 0 else n_points - 1
    pt = int(h5["loops/point"][p]) if "loops/point" in h5 else p
    lines = [f"Masing check at solution point {pt} (tol = {m.attrs['tol']:g}):",
             f"{'elem':>5} {'dev_manifold':>13} {'dev_masing':>11} {'on_manif':>9} "
             f"{'on_masing':>9} {'Eq.4':>5} {'Eq.6':>5} {'eq4_margin':>11} {'eq6_margin':>11}"]
    rows = range(ne) if ne <= max_rows else list(range(max_rows // 2)) + \
        list(range(ne - max_rows // 2, ne))
    for e in rows:
        lines.append(f"{e:>5} {m['dev_manifold'][p, e]:>13.3e} {m['dev_masing'][p, e]:>11.3e} "
                     f"{_fmt_bool(m['on_manifold'][p, e]):>9} "
                     f"{_fmt_bool(m['on_masing'][p, e]):>9} "
                     f"{_fmt_bool(m['eq4_ok'][p, e]):>5} {_fmt_bool(m['eq6_ok'][p, e]):>5} "
                     f"{m['eq4_margin'][p, e]:>11.3g} {m['eq6_margin'][p, e]:>11.3g}")
    if ne > max_rows:
        lines.insert(2 + max_rows // 2, f"{'...':>5} ({ne - max_rows} elements not shown)")
    on = m["on_manifold"][p]
    lines.append(f"on manifold: {int(on.sum())}/{ne}; on classical Masing: "
                 f"{int(m['on_masing'][p].sum())}/{ne}")
    return "\n".join(lines)


def sections() -> dict:
    """group name -> function(h5) -> str: the sections of ``jointsim info``, in order."""
    from . import fe_plots, hbm_plots, study_plots, transient_plots
    return {
        "static": fe_plots.static_table,
        "modes": fe_plots.modes_table,
        "hbm": hbm_plots.hbm_section,
        "epmc": hbm_plots.epmc_section,
        "transient": transient_plots.transient_table,
        "crosscheck": transient_plots.crosscheck_table,
        "qsma": study_plots.qsma_section,
        "contacts": study_plots.study_section,
    }


def info_text(path) -> str:
    """Summary of a result file: provenance, status, and each analysis' table."""
    path = Path(path)
    with open_result(path) as h5:
        a = h5.attrs
        lines = [f"{path}",
                 f"  scene: {a.get('scene_path', '?')} ({a.get('model_kind', '?')} model)",
                 f"  jointsim {a.get('jointsim_version', '?')}, schema "
                 f"{a.get('schema_version', '?')}, created {a.get('created', '?')}",
                 f"  status: {a.get('status', '?')}"
                 + (f" ({a['message']})" if a.get("message") else "")]
        if "wall_time_s" in a:
            lines.append(f"  wall time: {float(a['wall_time_s']):.2f} s")
        if "prescribed" in h5:
            g = h5["prescribed"]
            lines.append(f"  prescribed motion: law {g.attrs['law']} ({g.attrs['reversal']} "
                         f"reversal), omega = {g.attrs['omega']:g} rad/s, "
                         f"{g.attrs['n_periods']} periods x {g.attrs['n_samples']} samples; "
                         f"{g.attrs['message']}")
        for name, fn in sections().items():
            if name in h5:
                text = fn(h5)
                if text:
                    lines.append(text)
        if "masing" in h5 and h5["masing/dev_manifold"].shape[0]:
            lines.append(masing_table(h5))
    return "\n".join(lines)


__all__ = ["info_text", "masing_table", "sections"]
