"""The README's study tables, printed from result files (issue 14).

Every number of the README sections "Results" and "The seed's Fig. 3,
reproduced" comes from files that ``jointsim run`` writes on committed scenes::

    jointsim run models/lap_joint.toml -o results/lap_joint.h5 --post
    jointsim run models/lap_joint_fixed_n.toml -o results/lap_joint_fixed_n.h5 --post
    python -m jointsim.post.study_tables results/lap_joint.h5 results/lap_joint_fixed_n.h5 \\
        --seed results/seed

``--seed DIR`` reads ``DIR/<case>_<reversal>.h5`` for the four seed Fig. 3
scenes and the three reversal laws, and runs the missing ones
(``jointsim run models/seed_fig3/<case>.toml --set joint.reversal=<reversal>``).

The tables are printed as Markdown, in the README's order: the backbone and
fraction table, the confusion table, the third column and the attribution
table, and the Fig. 3 table.  All numbers come from :mod:`jointsim.post.study`.
"""
from __future__ import annotations

import argparse
import logging
from pathlib import Path

import h5py
import numpy as np

from . import study

log = logging.getLogger(__name__)

SEED_CASES = {"const": "5", "sin1": "sin(wt) + 5", "sin2": "sin(2wt) + 5",
              "sep": "max(0, 4 sin(2wt) + 3)"}
SEED_LAWS = ("scaled", "anchor", "manifold")


def _scene_label(h5) -> str:
    return "fixed N" if "fixed" in Path(str(h5.attrs.get("scene_path", ""))).stem else "coupled N"


def results_rows(h5: h5py.File, label: str | None = None) -> list[str]:
    """Rows of the README "Results" table for one scene (EPMC loop amplitudes).

    ``label`` is the scene column (default "fixed N" or "coupled N" from the scene
    file's name); a run that is not complete is marked with its status.
    """
    sets = study.loop_points(h5, study.study_group(h5))
    label = label or _scene_label(h5)
    status = h5.attrs.get("status", "complete")
    if status != "complete":
        label = f"{label} (run {status})"
    rows = study.backbone_comparison(h5, sets.parameter)
    man, mas, n = study.manifold_fractions(sets)
    w = study.fraction_weights(h5, sets.loaded.shape[1]).get("area")
    wm, ws, _ = study.weighted_fractions(sets, w) if w is not None else (man * np.nan,) * 3
    out = []
    for i, r in enumerate(rows):
        m = sets.loaded[i]
        out.append(
            f"| {label} | {r.amplitude:.2e} | {r.f_epmc:.2f} | {r.f_qsma:.2f} | "
            f"{_signed(100 * r.df_rel, 2)} % | {100 * r.zeta_epmc:.3f} % | "
            f"{100 * r.zeta_qsma:.3f} % | {_signed(100 * r.dzeta_rel, 1)} % | "
            f"{man[i]:.2f} ({int((sets.on_manifold[i] & m).sum())}"
            f"/{n[i]}) | {mas[i]:.2f} ({int((sets.on_masing[i] & m).sum())}/{n[i]}) | "
            f"{wm[i]:.2f} / {ws[i]:.2f} |")
    return out


def _signed(x: float, digits: int) -> str:
    """``x`` with its sign and ``digits`` decimals; a value that rounds to zero is
    ``+0.0..`` (its sign is round-off: the fixed-N joint's EPMC and QSMA agree to 1e-12
    at the lowest amplitude, and the sign of their difference changed with the model's
    round-off)."""
    v = round(float(x), digits)
    return f"{0.0 if v == 0 else v:+.{digits}f}"


def headline(h5: h5py.File) -> list[str]:
    """Largest deviations, clip and separation counts of a scene (for the bullets)."""
    sets = study.loop_points(h5, study.study_group(h5))
    m = sets.loaded
    lines = [f"{_scene_label(h5)}: {int(m.sum())} loaded pairs; largest dev_manifold "
             f"{sets.dev_manifold[m].max():.2g}, dev_masing {sets.dev_masing[m].max():.2g}; "
             f"separating {int((sets.separating & m).sum())}; manifold clipped "
             f"(excess > 1e-12) {int((sets.clipped & m).sum())}, excess > 0.01 "
             f"{int(((sets.manifold_excess > 0.01) & m).sum())}"]
    for i in range(sets.u.shape[0]):
        mi = m[i]
        lines.append(f"  a = {sets.parameter[i]:.3g}: on {int((sets.on_manifold[i] & mi).sum())}"
                     f"/{int(mi.sum())}, separating {int((sets.separating[i] & mi).sum())}, "
                     f"clipped {int((sets.clipped[i] & mi).sum())}, max excess "
                     f"{sets.manifold_excess[i][mi].max() if mi.any() else 0:.3g}")
    return lines


def confusion_table(h5: h5py.File) -> list[str]:
    sets = study.loop_points(h5, study.study_group(h5))
    c = study.condition_confusion(sets)
    return [f"{_scene_label(h5)}: {c.total} pairs, precision {c.precision:.2f}, "
            f"recall {c.recall:.2f}",
            "|  | off the manifold | on the manifold |", "|---|---|---|",
            f"| Eq. 4 or Eq. 6 violated | {c.violated_off} | {c.violated_on} |",
            f"| both conditions hold | {c.holds_off} | {c.holds_on} |"]


def control_table(h5: h5py.File) -> list[str]:
    """Third-column rows and the attribution table of one scene."""
    sets = study.loop_points(h5, study.study_group(h5))
    control = study.control_sets(h5, sets.group)
    if control is None:
        return [f"{_scene_label(h5)}: no /{sets.group}/control"]
    label = _scene_label(h5)
    phys, _, _ = study.manifold_fractions(sets)
    on, adm, dev = study.control_fractions(sets, control)
    m = sets.loaded
    out = [f"{label}: replay error max {control.replay_error[m].max():.2g}; control dev max "
           f"{control.dev_manifold[m].max():.2g} (closed loops: {dev.max():.2g}); "
           f"non-periodicity max {control.periodicity[m].max():.2g}; "
           f"control unclipped construction outside mu N: "
           f"{int(((control.excess > 1e-12) & m).sum())} of {int(m.sum())}",
           "| scene | modal amplitude [sqrt(kg) m] | physical law on its manifold | "
           "manifold law (control) on its manifold | physical manifold clipped at +-mu N | "
           "separating |", "|---|---|---|---|---|---|"]
    for i in range(sets.u.shape[0]):
        mi = m[i]
        out.append(f"| {label} | {sets.parameter[i]:.2e} | {phys[i]:.2f} | {on[i]:.2f} | "
                   f"{int((sets.clipped[i] & mi).sum())}/{int(mi.sum())} | "
                   f"{int((sets.separating[i] & mi).sum())}/{int(mi.sum())} |")
    att = study.attribution(sets, control)
    out.append("")
    out.append(f"Attribution, {label} ({att.total} pairs; cell: count (separating, clipped)):")
    out.append("|  | " + " | ".join(("on the manifold" if c == "on manifold" else f"off: {c}")
                                   for c in att.columns) + " |")
    out.append("|---" * (len(att.columns) + 1) + "|")
    total = study.Attribution(att.columns, att.count.sum(0, keepdims=True),
                              att.separating.sum(0, keepdims=True),
                              att.clipped.sum(0, keepdims=True))
    for name, a, i in (("Eq. 4 or Eq. 6 violated", att, 0), ("both conditions hold", att, 1),
                       ("total", total, 0)):
        out.append(f"| {name} | " + " | ".join(a.cell(i, j) for j in range(len(att.columns)))
                   + " |")
    return out


def seed_table(folder: Path) -> list[str]:
    """The README's Fig. 3 table, from ``folder/<case>_<reversal>.h5`` (run when missing)."""
    from ..run import run_scene
    from ..scene import load_scene

    root = Path(__file__).resolve().parents[2] / "models" / "seed_fig3"
    folder.mkdir(parents=True, exist_ok=True)
    out = ["| scene | N(t) | reversal | dev_manifold | dev_masing | on manifold | "
           "manifold excess (unclipped) | Eq. 4 | Eq. 6 |",
           "|---|---|---|---|---|---|---|---|---|"]

    def verdict(ok, margin):
        return "holds" if ok else f"violated ({margin:.3f})"

    for law in SEED_LAWS:
        for case, ntext in SEED_CASES.items():
            path = folder / f"{case}_{law}.h5"
            if not path.exists():
                run_scene(load_scene(root / f"{case}.toml", [f"joint.reversal={law}"]), path)
            with h5py.File(path, "r") as h5:
                m = {k: h5[f"masing/{k}"][0, 0] for k in h5["masing"]
                     if h5[f"masing/{k}"].ndim == 2}
            out.append(f"| `{case}` | {ntext} | {law} | {m['dev_manifold']:.1e} | "
                       f"{m['dev_masing']:.3f} | {'yes' if m['on_manifold'] else 'no'} | "
                       f"{m['manifold_excess']:.1e} | {verdict(m['eq4_ok'], m['eq4_margin'])} | "
                       f"{verdict(m['eq6_ok'], m['eq6_margin'])} |")
    return out


def settings(h5: h5py.File) -> str:
    """One line: the EPMC's harmonics and samples, the QSMA points and the run status."""
    e = h5["epmc"]
    hs = e["harmonics"][()].tolist() if "harmonics" in e else []
    span = f"{hs[0]}..{hs[-1]} ({len(hs)})" if hs else "?"
    q = h5["qsma/amplitude"].shape[0] if "qsma/amplitude" in h5 else "-"
    return (f"{h5.filename}: EPMC harmonics {span}, Nt = {e.attrs.get('n_samples', '?')}; "
            f"QSMA points {q}; status {h5.attrs.get('status', '?')}")


def main(argv=None) -> None:
    p = argparse.ArgumentParser(prog="python -m jointsim.post.study_tables",
                                description=__doc__.splitlines()[0])
    p.add_argument("files", nargs="*", type=Path, help="lap-joint result files")
    p.add_argument("--seed", type=Path, help="folder of the seed Fig. 3 result files")
    p.add_argument("--label", action="append", default=[],
                   help="scene column of each file's rows, in order (default from the scene)")
    args = p.parse_args(argv)
    labels = args.label + [None] * (len(args.files) - len(args.label))
    logging.basicConfig(level=logging.WARNING)
    blocks = []
    for f, label in zip(args.files, labels):
        with h5py.File(f, "r") as h5:
            blocks.append(settings(h5))
            blocks.append("\n".join(results_rows(h5, label)))
            blocks.append("\n".join(headline(h5)))
            blocks.append("\n".join(confusion_table(h5)))
            blocks.append("\n".join(control_table(h5)))
    if args.seed is not None:
        blocks.append("\n".join(seed_table(args.seed)))
    print("\n\n".join(blocks))


if __name__ == "__main__":
    main()
