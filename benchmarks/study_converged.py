"""The coupled study table at converged harmonics (issue 12 item 5; not collected by pytest).

Runs the coupled lap joint's EPMC, QSMA and Masing check (what the README
"Results" table needs: modes, QSMA, EPMC with its loop sets; no FRC) at a ladder
of harmonics H = 0..15, 0..19, 0..23 and the reference 0..31, each with
``Nt = 8 (2H + 1)`` rounded up to a power of 2 (256, 512, 512, 512), and
compares every setting with the most refined complete one::

    python benchmarks/study_converged.py run [--H 15 19 23 31] [--out results/study23]
    python benchmarks/study_converged.py compare [--H 15 19 23 31] [--out results/study23]
    python benchmarks/study_converged.py refine --H 15 --to 15 31 --amps 3e-4 1e-3 3e-3

``run`` writes a copy of ``models/lap_joint.toml`` (``--scene``) without ``[analysis.hbm]``
to ``OUT/lap_joint_study.toml`` and runs, one at a time (one process each),::

    python -m jointsim.cli run OUT/lap_joint_study.toml -o OUT/h<H>.h5 \\
        --set analysis.epmc.harmonics=[0,...,H] --set analysis.epmc.n_samples=<Nt> \\
        --set analysis.epmc.amplitudes=[1e-4,3e-4,1e-3,3e-3] \\
        --set analysis.epmc.log10_amplitude_end=-2.45 \\
        --set analysis.epmc.error_indicators=false

with its log in ``OUT/h<H>.log``; a complete file is kept, an interrupted one
is continued with ``--resume``.  ``analysis.epmc.amplitudes`` solves the mode
exactly at the four loop amplitudes (``/epmc/at_amplitudes``), so the ladder
compares frequency and damping there without interpolating along the branch;
the branch ends at log10 a = -2.45, past the last loop amplitude (3e-3,
-2.52), as in the coupled ``converge`` ladder (the scene's -2.4 only adds
macroslip points that drift, README "The low-H EPMC").

``compare`` prints, per setting, the largest relative errors against the
reference of (a) the EPMC frequency and damping solved at the four loop
amplitudes, (b) the EPMC and QSMA frequency and damping interpolated along the
branches at the loop amplitudes and the area-weighted on-manifold and
on-Masing shares of the four loop sets (absolute), as ``jointsim converge``
measures them (:func:`jointsim.quantities.quantities`), then names the least
refined setting within 1 % in every frequency and 5 % in every damping ratio
and prints its rows of the README study table
(:func:`jointsim.post.study_tables.results_rows`), its element counts, the
conditions' confusion table and the control's summary line.  A damping
ratio solved at 1e-4 that did not converge (NaN; at H = 0..15 Newton stalls
there in a piece of small folds, README "EPMC hard cases") is left out of
(a); (b) still covers that amplitude.
"""
from __future__ import annotations

import argparse
import logging
import re
import subprocess
import sys
from pathlib import Path

import h5py
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from jointsim.quantities import errors, quantities  # noqa: E402
from jointsim.post.study import fraction_weights, loop_points, weighted_fractions  # noqa: E402
from jointsim.post.study_tables import (confusion_table, control_table, headline,  # noqa: E402
                                        results_rows)
from jointsim.scene import load_scene  # noqa: E402

log = logging.getLogger("study_converged")

LOOP_AMPLITUDES = "[1e-4,3e-4,1e-3,3e-3]"
END = -2.45
RTOL_FREQUENCY = 1e-2
RTOL_DAMPING = 5e-2


def n_samples(H: int) -> int:
    """AFT samples for harmonics 0..H: ``8 (2H + 1)`` rounded up to a power of 2."""
    return int(2 ** np.ceil(np.log2(8 * (2 * H + 1))))


def overrides(H: int) -> list[str]:
    """The ``--set`` items of the setting H (also used to load the scene for comparing)."""
    return [f"analysis.epmc.harmonics=[{','.join(str(h) for h in range(H + 1))}]",
            f"analysis.epmc.n_samples={n_samples(H)}",
            f"analysis.epmc.amplitudes={LOOP_AMPLITUDES}",
            f"analysis.epmc.log10_amplitude_end={END}",
            "analysis.epmc.error_indicators=false"]   # the table does not use them


def write_scene(out: Path, source: Path = ROOT / "models" / "lap_joint.toml") -> Path:
    """Copy of the coupled scene ``source`` without ``[analysis.hbm]`` (the table needs
    no FRC)."""
    src = Path(source).read_text()
    text = re.sub(r"\n\[analysis\.hbm\]\n(?:(?!\n\[).)*", "\n", src, flags=re.S)
    rel = Path(*[".."] * len(out.resolve().relative_to(ROOT).parts))
    text = text.replace('mesh = "../meshes/', f'mesh = "{rel.as_posix()}/meshes/')
    if "[analysis.hbm]" in text or "[analysis.epmc]" not in text:
        raise RuntimeError(f"could not derive the study scene from {source}")
    path = out / "lap_joint_study.toml"
    if not path.exists() or path.read_text() != text:
        path.write_text(text)
    return path


def _status(path: Path) -> str | None:
    if not path.exists():
        return None
    with h5py.File(path, "r", locking=False) as h5:
        return str(h5.attrs.get("status", "unknown"))


def run(ladder: list[int], out: Path, source: Path = ROOT / "models" / "lap_joint.toml") -> int:
    """Run each setting in turn (complete files are kept, others resumed)."""
    out.mkdir(parents=True, exist_ok=True)
    scene = write_scene(out, source)
    rc = 0
    for H in ladder:
        f = out / f"h{H}.h5"
        st = _status(f)
        if st == "complete":
            log.info("H = %d: %s complete, kept", H, f)
            continue
        cmd = [sys.executable, "-m", "jointsim.cli", "run", str(scene), "-o", str(f)]
        for s in overrides(H):
            cmd += ["--set", s]
        if st is not None:
            cmd.append("--resume")
        log.info("H = %d, Nt = %d: %s", H, n_samples(H), " ".join(cmd))
        with open(out / f"h{H}.log", "a") as logf:
            r = subprocess.run(cmd, stdout=logf, stderr=subprocess.STDOUT, cwd=ROOT)
        log.info("H = %d: exit %d, status %s", H, r.returncode, _status(f))
        rc = rc or r.returncode
    return rc


def at_amplitudes(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """EPMC frequency [Hz] and damping ratio solved at the loop amplitudes (NaN: not solved)."""
    with h5py.File(path, "r", locking=False) as h5:
        g = h5.get("epmc/at_amplitudes")
        if g is None:
            return np.full(4, np.nan), np.full(4, np.nan)
        ok = g["converged"][()]
        return (np.where(ok, g["frequency_hz"][()], np.nan),
                np.where(ok, g["damping_ratio"][()], np.nan))


def _mx(e) -> float:
    e = np.asarray(e, dtype=float)
    e = e[~np.isnan(e)]
    return float(e.max()) if e.size else np.nan


def _fmt(v: float) -> str:
    return "-" if np.isnan(v) else ("not reached" if np.isinf(v) else f"{v:.1e}")


def compare(ladder: list[int], out: Path) -> int:
    """Print the ladder's errors against its most refined complete run, and the table."""
    files = {H: out / f"h{H}.h5" for H in ladder}
    info = {}
    for H, f in files.items():
        st = _status(f)
        if st is None:
            print(f"H = {H}: no file {f}")
            continue
        with h5py.File(f, "r", locking=False) as h5:
            e = h5.get("epmc")
            info[H] = dict(status=st, wall=float(h5.attrs.get("wall_time_s", np.nan)),
                           points=int(e["amplitude"].shape[0]) if e and "amplitude" in e else 0,
                           last=(float(np.log10(e["amplitude"][-1]))
                                 if e and "amplitude" in e and e["amplitude"].shape[0] else np.nan),
                           branch=str(e.attrs.get("branch_status", "-")) if e else "-",
                           message=str(e.attrs.get("message", "")) if e else "",
                           epmc_s=float(e.attrs.get("time_s", np.nan)) if e else np.nan)
    complete = [H for H in ladder if info.get(H, {}).get("status") == "complete"]
    if not complete:
        print("no complete run")
        return 1
    ref_H = max(complete)
    scene = {H: load_scene(str(out / "lap_joint_study.toml"), overrides(H)) for H in info}
    ref_q = quantities(files[ref_H], scene[ref_H])
    names = [q.name for q in ref_q]
    rf, rz = at_amplitudes(files[ref_H])
    print(f"reference H = 0..{ref_H}, Nt = {n_samples(ref_H)}; EPMC solved at the loop "
          f"amplitudes: f = {np.array2string(rf, precision=3)} Hz, zeta = "
          f"{np.array2string(100 * rz, precision=4)} %")
    print("| H | Nt | status | EPMC points | wall [s] (EPMC [s]) | EPMC f at a (solved) | "
          "EPMC zeta at a (solved) | EPMC f (branch) | EPMC zeta (branch) | QSMA f | QSMA zeta "
          "| shares (abs.) |")
    print("|---" * 12 + "|")
    pick = None
    for H in ladder:
        if H not in info:
            continue
        s = info[H]
        f, z = at_amplitudes(files[H])
        # an exact solve that did not converge in this setting is left out of (a):
        # (b) covers its amplitude along the branch
        ef, ez = np.abs(f - rf) / np.abs(rf), np.abs(z - rz) / np.abs(rz)
        unsolved = [f"{x:g}" for x, v in zip(eval(LOOP_AMPLITUDES), f) if np.isnan(v)]
        e = errors(quantities(files[H], scene[H]), ref_q)

        def sel(prefix, what):
            return _mx([x for n, x in zip(names, e) if n.startswith(prefix) and what in n])

        row = dict(ef=_mx(ef), ez=_mx(ez), bf=sel("EPMC", "frequency"),
                   bz=sel("EPMC", "damping"), qf=sel("QSMA", "frequency"),
                   qz=sel("QSMA", "damping"), sh=sel("epmc set", "share"))
        if H == ref_H:
            cells = ["reference"] * 7
        else:
            cells = [_fmt(row[k]) for k in ("ef", "ez", "bf", "bz", "qf", "qz", "sh")]
        print(f"| {H} | {n_samples(H)} | {s['status']}, EPMC {s['branch']} | {s['points']} | "
              f"{s['wall']:.0f} ({s['epmc_s']:.0f}) | " + " | ".join(cells) + " |")
        if s["branch"] != "complete":
            print(f"|   | last point at log10 a = {s['last']:.4f}; message: "
                  f"{s['message'] or s['status']} |")
        meets = (H != ref_H and s["status"] == "complete"
                 and max(row["ef"], row["bf"], row["qf"]) <= RTOL_FREQUENCY
                 and max(row["ez"], row["bz"], row["qz"]) <= RTOL_DAMPING)
        if meets and pick is None:
            pick = H
        if H != ref_H:
            fm = {"float_kind": lambda v: f"{v:.1e}"}
            print(f"|   | solved, per amplitude: f {np.array2string(ef, formatter=fm)}, zeta "
                  f"{np.array2string(ez, formatter=fm)}"
                  + (f" (not solved at a = {', '.join(unsolved)})" if unsolved else "") + " |")
    if pick is None:
        print(f"\nno setting below H = {ref_H} meets {RTOL_FREQUENCY:g} / {RTOL_DAMPING:g}; "
              f"the rows of the reference H = 0..{ref_H}:\n")
    else:
        print(f"\nleast refined setting within {RTOL_FREQUENCY:.0%} in frequency and "
              f"{RTOL_DAMPING:.0%} in damping of H = 0..{ref_H}: H = 0..{pick}, "
              f"Nt = {n_samples(pick)}\n")
    show = ref_H if pick is None else pick
    for H in complete:
        with h5py.File(files[H], "r", locking=False) as h5:
            sets = loop_points(h5, "epmc")
            w = fraction_weights(h5, sets.loaded.shape[1])["area"]
            man, mas, _ = weighted_fractions(sets, w)
            g3 = {"float_kind": lambda v: f"{v:.3g}"}
            print(f"H = {H}: loop sets at a = {np.array2string(sets.parameter, formatter=g3)}, "
                  f"area shares manifold {np.array2string(man, precision=2)}, Masing "
                  f"{np.array2string(mas, precision=2)}")
    print()
    with h5py.File(files[show], "r", locking=False) as h5:
        for r in results_rows(h5, f"coupled N, H 0..{show}, Nt {n_samples(show)}"):
            print(r)
        print()
        for r in headline(h5) + confusion_table(h5) + control_table(h5)[:1]:
            print(r)
    return 0 if pick is not None else 2


def refine(files: list[Path], targets: list[int], scene_path: Path, amps=None) -> dict:
    """EPMC frequency and damping at the loop amplitudes at finer harmonics, by Newton
    at fixed amplitude from a coarser run's branch (no continuation).

    For each file and each target H' (above the file's H), the file's branch
    (``/epmc/y``) is interpolated in log10 a at each loop amplitude (the first
    crossing, as :func:`jointsim.analyses.epmc_exact.solve_at_amplitudes` does), the
    harmonics the file does not keep start at zero (``_embed`` of
    ``benchmarks/accuracy_cost.py``), and Newton solves the mode at H' with
    ``Nt = n_samples(H')`` (tolerance 1e-8 on ``max|R| / rscale``, at most 40
    iterations, dense linear solves).  This is the reference the ladder falls back
    on when the continuation at H' does not finish.

    Returns
    -------
    dict
        ``(file, H') -> (f [Hz], zeta, converged)``, each of shape (n_amps,)
        (``amps``, default the four loop amplitudes).
    """
    from accuracy_cost import _embed
    from jointsim.analyses.epmc import _linear_start, _scales
    from jointsim.model import build_model
    from jointsim.scene import EPMCAnalysis
    from jointsim.solvers.condensation import dense_array
    from jointsim.solvers.epmc import EPMCSystem
    from jointsim.solvers.hbm import HBMSystem
    from jointsim.solvers.modes import elastic_mode
    from jointsim.solvers.newton import NewtonOptions, newton

    model = build_model(load_scene(str(scene_path)))
    em = elastic_mode(model, 1, None)
    xi0 = float(em.phi @ dense_array(model.C) @ em.phi)
    amps = np.array(amps if amps else eval(LOOP_AMPLITUDES), dtype=float)
    a0 = EPMCAnalysis(log10_amplitude_start=-5.0, log10_amplitude_end=END)
    out = {}
    for f in files:
        with h5py.File(f, "r", locking=False) as h5:
            Y = h5["epmc/y"][()]
            H0 = int(np.max(h5["epmc/harmonics"][()]))
            nt0 = n_samples(H0)
        s0 = HBMSystem(model, tuple(range(H0 + 1)), nt0, linear_solver="direct")
        for Ht in targets:
            if Ht < H0:   # Ht == H0 reproduces the file's own solves (a check)
                continue
            sys_ = HBMSystem(model, tuple(range(Ht + 1)), n_samples(Ht), linear_solver="direct")
            ep = EPMCSystem(sys_, em.phi, sys_.force_coefficients(0.0))
            scale, rscale = _scales(ep, _linear_start(a0, sys_, em, xi0), em.omega)
            nz = sys_.n_z
            sz = scale[:nz + 2]
            fr, ze = np.full(amps.size, np.nan), np.full(amps.size, np.nan)
            ok = np.zeros(amps.size, bool)
            for k, amp in enumerate(amps):
                lt = float(np.log10(amp))
                lam = Y[:, -1]
                seg = np.flatnonzero((lam[:-1] - lt) * (lam[1:] - lt) <= 0.0)
                if seg.size == 0:
                    continue
                i = int(seg[0])
                w = (lt - lam[i]) / (lam[i + 1] - lam[i]) if lam[i + 1] != lam[i] else 0.0
                g = _embed(((1 - w) * Y[i] + w * Y[i + 1])[:-1], s0.basis, sys_.basis,
                           sys_.n_r)

                def fun(zs, lt=lt):
                    R, J, ev = ep.fun(np.append(zs * sz, lt))
                    return R / rscale, J[:, :nz + 2] * sz[None, :] / rscale, ev

                res = newton(fun, g / sz, NewtonOptions(1e-8, 40, check_start=True))
                log.info("%s -> H = %d at a = %g: %s", f.name, Ht, amp, res.message)
                if res.success:
                    y = res.x * sz
                    fr[k], ze[k], ok[k] = y[nz] / (2 * np.pi), y[nz + 1] / (2 * y[nz]), True
            out[(f.name, Ht)] = (fr, ze, ok)
            print(f"{f.name} -> H = 0..{Ht}, Nt = {n_samples(Ht)} (Newton at fixed a): "
                  f"f = {np.array2string(fr, precision=3)} Hz, zeta = "
                  f"{np.array2string(100 * ze, precision=4)} %", flush=True)
    # every file's own solves against the finest refined values (from the first file
    # that reached them): the ladder's errors against H' when H' did not complete
    Ht = max(targets)
    ref = next((v for (name, t), v in out.items() if t == Ht), None)
    if ref is not None:
        all_amps = np.array(eval(LOOP_AMPLITUDES), dtype=float)
        idx = [int(np.argmin(np.abs(all_amps - x))) for x in amps]
        fm = {"float_kind": lambda v: f"{v:.1e}"}
        for f in files:
            fo, zo = at_amplitudes(f)
            ef = np.abs(fo[idx] - ref[0]) / ref[0]
            ez = (zo[idx] - ref[1]) / ref[1]
            ok = (np.nanmax(ef) <= RTOL_FREQUENCY) and (np.nanmax(np.abs(ez)) <= RTOL_DAMPING)
            print(f"{f.name} against H = 0..{Ht} at a = {amps.tolist()}: f "
                  f"{np.array2string(ef, formatter=fm)}, zeta {np.array2string(ez, formatter=fm)}"
                  f" -> {'meets' if ok else 'misses'} {RTOL_FREQUENCY:.0%} / {RTOL_DAMPING:.0%}")
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("what", choices=("run", "compare", "refine"))
    p.add_argument("--H", type=int, nargs="+", default=[15, 19, 23, 31],
                   help="highest harmonic of each setting, coarse to fine")
    p.add_argument("--out", type=Path, default=ROOT / "results" / "study23")
    p.add_argument("--to", type=int, nargs="+", default=[31],
                   help="refine: target highest harmonics")
    p.add_argument("--amps", type=float, nargs="+", default=None,
                   help="refine: modal amplitudes (default the four loop amplitudes)")
    p.add_argument("--scene", type=Path, default=ROOT / "models" / "lap_joint.toml",
                   help="run: the coupled scene (models/lap_joint_nodes.toml: the node-pair "
                        "study of rounds up to 14)")
    a = p.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    ladder = sorted(a.H)
    if a.what == "refine":
        refine([a.out / f"h{H}.h5" for H in ladder], a.to, a.out / "lap_joint_study.toml",
               a.amps)
        return 0
    return run(ladder, a.out, a.scene) if a.what == "run" else compare(ladder, a.out)


if __name__ == "__main__":
    sys.exit(main())
