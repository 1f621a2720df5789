"""Command line: ``jointsim run | post | info``.

``jointsim run SCENE [-o OUT.h5] [--set key=value ...] [--post]``
    Validate the scene (nothing is written if it is invalid), run its
    analyses, and write the result file (default ``results/<scene>.h5``).
``jointsim post OUT.h5 [OUT2.h5 ...]``
    Make the figures of result files (next to each file, in ``<stem>_figures/``).
``jointsim info OUT.h5``
    Print a summary table.
``jointsim check SCENE [--set key=value ...]``
    Validate a scene and print the kernels it selects, the model sizes, the
    analyses that will run and the effects that are off (with what that skips).
``jointsim sweep SCENE --vary key=v1,v2,... [--scheduler ADDRESS]``
    Run every combination of parameter values on dask.distributed.
``jointsim converge SCENE [--rtol R] [--dials D ...] [--workers N] [-o DIR]``
    Run the scene at a ladder of settings per numerical dial, report errors
    and wall times, and recommend the cheapest setting within ``--rtol``.
``jointsim keys``
    Print every scene key with its default, unit and meaning (markdown).
"""
from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path

from .scene import SceneError, load_scene

log = logging.getLogger("jointsim")


def _parser() -> argparse.ArgumentParser:
    common = argparse.ArgumentParser(add_help=False)
    common.add_argument("-v", "--verbose", action="store_true", help="debug log output")
    common.add_argument("-q", "--quiet", action="store_true", help="only warnings and errors")
    p = argparse.ArgumentParser(prog="jointsim", description=__doc__.split("\n")[0])
    sub = p.add_subparsers(dest="command", required=True)

    r = sub.add_parser("run", parents=[common], help="run a scene and write its result file")
    r.add_argument("scene", help="scene file (TOML)")
    r.add_argument("-o", "--output", help="result file (default: results/<scene>.h5)")
    r.add_argument("--set", dest="overrides", action="append", default=[],
                   metavar="KEY=VALUE", help="override a scene key (repeatable)")
    r.add_argument("--resume", action="store_true",
                   help="continue an interrupted result file of the same scene")
    r.add_argument("--overwrite", action="store_true",
                   help="replace an existing result file (otherwise it is refused)")
    r.add_argument("--post", action="store_true", help="make the figures afterwards")
    r.add_argument("--preset", choices=("fast", "balanced", "reference"), default=None,
                   help="numerical settings for the keys the scene does not give "
                        "explicitly (jointsim/presets.py)")

    q = sub.add_parser("post", parents=[common], help="make figures from result files")
    q.add_argument("results", nargs="+", help="result files (HDF5)")
    q.add_argument("-d", "--outdir", help="figure folder (default: <stem>_figures/ "
                                          "next to each file)")
    q.add_argument("--rad-s", action="store_true",
                   help="frequency response figures in rad/s (default: Hz)")

    i = sub.add_parser("info", parents=[common], help="print a summary of a result file")
    i.add_argument("result", help="result file (HDF5)")

    w = sub.add_parser("sweep", parents=[common],
                       help="run a scene for every combination of parameter values (dask)")
    w.add_argument("scene")
    w.add_argument("--vary", action="append", default=[], metavar="KEY=V1,V2,...",
                   help="a sweep axis (repeatable; the sweep is their Cartesian product)")
    w.add_argument("--set", dest="overrides", action="append", default=[],
                   metavar="KEY=VALUE", help="override applied to every run")
    w.add_argument("-o", "--outdir", default=None,
                   help="folder of the result files (default: results/<scene>_sweep)")
    w.add_argument("--scheduler", default=None,
                   help="address of a running dask scheduler (default: a local cluster)")
    w.add_argument("--workers", type=int, default=2, help="workers of the local cluster")

    cv = sub.add_parser("converge", parents=[common],
                        help="errors and wall times at a ladder of settings per dial, and "
                             "the cheapest setting within --rtol")
    cv.add_argument("scene")
    cv.add_argument("--rtol", type=float, default=1e-2, help="requested accuracy")
    cv.add_argument("--dials", nargs="+", default=None,
                    help="dials to ladder (default: every one the scene uses): harmonics, "
                         "samples, tol, dx_lap, steps, iwan_rtol")
    cv.add_argument("--ladder", action="append", default=[], metavar="DIAL=V1,V2,...",
                    help="replace a dial's ladder (least refined first; the last is the "
                         "reference), e.g. harmonics=3,5,7,11")
    cv.add_argument("--set", dest="overrides", action="append", default=[],
                    metavar="KEY=VALUE", help="override applied to every run")
    cv.add_argument("-o", "--outdir", default=None,
                    help="folder of the runs, converge.h5 and the figures "
                         "(default: results/<scene>_converge)")
    cv.add_argument("--scheduler", default=None,
                    help="address of a running dask scheduler (default: a local cluster)")
    cv.add_argument("--workers", type=int, default=2, help="workers of the local cluster")

    sub.add_parser("keys", parents=[common], help="print every scene key as a markdown table")

    c = sub.add_parser("check", parents=[common], help="validate a scene without running it")
    c.add_argument("scene")
    c.add_argument("--set", dest="overrides", action="append", default=[],
                   metavar="KEY=VALUE")
    return p


def _model_size(scene) -> str:
    """The sizes of the scene's model that are known without building it."""
    m = scene.model
    loads = len(scene.excitation.loads)
    if m.kind == "prescribed":
        return (f"prescribed motion of one contact element, {m.n_periods} periods x "
                f"{m.n_samples} samples ({m.units} units)")
    if m.kind == "lumped":
        return (f"lumped, {m.n_dof} DOFs, {len(m.contacts)} contact element(s), {loads} "
                f"load(s) ({m.units} units)")
    if m.kind == "fe":
        size = ""
        try:
            from .model.fe import fe_mesh
            mesh, source = fe_mesh(scene)      # the file read, or the mesh generated
            n_nodes = mesh.points.shape[0]
            size = (f"{source}: {n_nodes} mesh nodes, {mesh.quads.shape[0]} quads "
                    f"(biquadratic elements on them); ")
        except Exception as exc:  # a check reports, it does not fail on a mesh reader
            size = f"mesh not read ({type(exc).__name__}: {exc}); "
        contact = ("node-to-node pairs" if m.contact_points == "nodes"
                   else f"{m.contact_gauss} Gauss points per interface edge")
        return (f"FE lap joint, {size}contact at {contact}; Craig-Bampton keeps "
                f"{m.n_modes} fixed-interface modes plus the interface, bolt and "
                f"{len(m.retain_points)} retained point DOFs; {len(m.bolts)} bolt(s), "
                f"{loads} load(s)")
    return f"{m.kind} model from {m.file}, {loads} load(s) ({m.units} units)"


def _analysis_line(name: str, sec, scene) -> str:
    """One line of ``jointsim check`` for an analysis the scene runs."""
    if name == "hbm":
        from .analyses.hbm import loop_rule
        return (f"hbm: {len(sec.force_scale)} branch(es) (force x "
                f"{', '.join(f'{v:g}' for v in sec.force_scale)}), omega {sec.omega_start:g} "
                f"to {sec.omega_end:g} rad/s, harmonics {list(sec.harmonics)}, "
                f"{sec.n_samples} samples; amplitude: {sec.amplitude}; loops kept: "
                f"{loop_rule(scene)}")
    if name == "epmc":
        extra = f"; solved at amplitudes {list(sec.amplitudes)}" if sec.amplitudes else ""
        return (f"epmc: mode {sec.mode}, modal amplitude 10^{sec.log10_amplitude_start:g} to "
                f"10^{sec.log10_amplitude_end:g}, harmonics {list(sec.harmonics)}{extra}")
    if name == "qsma":
        return (f"qsma: mode {sec.mode}, modal amplitude 10^{sec.log10_amplitude_start:g} to "
                f"10^{sec.log10_amplitude_end:g}, {sec.n_steps} steps")
    if name == "transient":
        what = f"steady at omega = {sec.omega:g} rad/s" if sec.omega > 0 else \
            f"free decay of mode {sec.mode} from amplitude {sec.amplitude:g}"
        return f"transient: {what}, {sec.steps_per_period} steps per period"
    if name == "modes":
        return f"modes: {sec.n_modes} linear modes of the stuck joint"
    return name


def check_text(scene, file: str) -> str:
    """What ``jointsim check`` prints: kernels, model sizes, the analyses that will
    run, and the effects that are off with what that skips."""
    k = scene.kernels()
    lines = [f"{file}: valid ({scene.model.kind} model, kernels {k.tangential}/{k.normal})",
             f"  model: {_model_size(scene)}"]
    if scene.model.kind == "prescribed":
        lines.append("  analyses: the prescribed march of the element (model.*) and its "
                     "Masing check")
    else:
        from .analyses import ORDER
        run = [(n, getattr(scene.analysis, n)) for n in ORDER
               if getattr(scene.analysis, n, None) is not None]
        if run:
            lines.append("  analyses, in run order:")
            lines += [f"    {_analysis_line(n, sec, scene)}" for n, sec in run]
        else:
            lines.append("  analyses: none (add an [analysis.<name>] table; nothing will "
                         "be computed but the static state)")
    fx, j = scene.effects, scene.joint
    off = []
    if not fx.friction:
        off.append("effects.friction = false: no tangential contact force (frictionless); "
                   "no friction damping, no hysteresis loops, no Masing checks")
    elif j.law == "stuck":
        off.append("joint.law = 'stuck': the joint never slips; no friction damping, "
                   "the response is linear in the tangential direction")
    if fx.normal == "fixed":
        off.append("effects.normal = 'fixed': the normal load is given and does not follow "
                   "the gap; no normal-tangential coupling, no separation")
    elif not fx.separation:
        off.append("effects.separation = false: the normal spring is bilateral; the "
                   "contact never opens (no loss of contact, no impacts)")
    if off:
        lines.append("  effects off:")
        lines += [f"    {t}" for t in off]
    else:
        lines.append("  effects off: none")
    return "\n".join(lines)


def default_output(scene_path: str) -> Path:
    return Path("results") / (Path(scene_path).stem + ".h5")


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    level = logging.WARNING if args.quiet else (logging.DEBUG if args.verbose else logging.INFO)
    logging.basicConfig(level=level, format="%(levelname)s %(name)s: %(message)s")
    logging.getLogger("numba").setLevel(logging.WARNING)
    logging.getLogger("matplotlib").setLevel(logging.WARNING)
    logging.getLogger("skfem").setLevel(logging.WARNING)
    from .blas import limit_blas_threads
    limit_blas_threads()
    try:
        if args.command in ("run", "check"):
            if getattr(args, "preset", None):
                from .presets import preset_overrides
                added = preset_overrides(args.scene, args.preset, args.overrides)
                log.info("preset %s sets %s", args.preset, " ".join(added) or "nothing")
                args.overrides = added + list(args.overrides)
            scene = load_scene(args.scene, args.overrides)
            if args.command == "check":
                print(check_text(scene, args.scene))
                return 0
            from .run import run_scene
            out = Path(args.output) if args.output else default_output(args.scene)
            run_scene(scene, out, resume=args.resume, overwrite=args.overwrite)
            print(out)
            if args.post:
                from .post import make_figures
                for fig in make_figures(out):
                    print(fig)
            return 0
        if args.command == "post":
            from .post import make_figures
            several = len(args.results) > 1
            for res in args.results:
                outdir = args.outdir
                if outdir and several:  # keep each file's figures apart
                    outdir = Path(outdir) / Path(res).stem
                for fig in make_figures(res, outdir, "rad/s" if args.rad_s else "Hz"):
                    print(fig)
            if len(args.results) > 1:
                from .post import combined_figures
                for fig in combined_figures(args.results, args.outdir):
                    print(fig)
            return 0
        if args.command == "sweep":
            from .sweep import run_sweep
            outdir = args.outdir or Path("results") / (Path(args.scene).stem + "_sweep")
            print(run_sweep(args.scene, args.vary, outdir, args.scheduler, args.workers,
                            args.overrides))
            return 0
        if args.command == "converge":
            from .converge import figures, run_converge, table_text
            from .converge import parse_ladders
            res = run_converge(args.scene, args.rtol, args.dials, args.outdir, args.scheduler,
                               args.workers, args.overrides,
                               ladders=parse_ladders(args.ladder, args.scene))
            print(table_text(res))
            for fig in figures(res):
                print(fig)
            print(res.outdir / "converge.h5")
            return 0 if res.check_ok else 1
        if args.command == "keys":
            from .scene import key_table
            print(key_table())
            return 0
        if args.command == "info":
            from .post.tables import info_text
            print(info_text(args.result))
            return 0
    except SceneError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except (FileNotFoundError, OSError, ValueError, NotImplementedError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    except RuntimeError as exc:
        print(f"error: run did not succeed: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt as exc:
        if args.command == "sweep":
            print(f"interrupted ({exc or 'SIGINT'}); finished variants are kept, rerun the "
                  "sweep to compute the others", file=sys.stderr)
        else:
            print(f"interrupted ({exc or 'SIGINT'}); the result file holds the committed "
                  "points; continue with --resume", file=sys.stderr)
        return 143 if "SIGTERM" in str(exc) else 130
    return 1


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
