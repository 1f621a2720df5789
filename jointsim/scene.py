"""Scene files: TOML in, frozen dataclasses out.

A scene declares everything a run needs: the model, the joint (contact law and
its parameters), the *effects* (which physics exist), damping, excitation and
the analyses to run.  Loading validates every key and names the file and the
key on the first error::

    models/x.toml: joint.mu must be >= 0, got -0.1

Any key can be overridden with ``--set key=value`` (values are parsed as TOML,
and fall back to a bare string, so ``--set joint.reversal=anchor`` works).
Nothing in a scene is ever evaluated as code.

Time-varying inputs (a prescribed motion, a normal load, a force) are
:class:`Signal` tables: a constant plus harmonics given by cosine and sine
coefficients, matching the harmonic-balance coefficient order
``[0, 1c, 1s, 2c, 2s, ...]``; optionally clipped at zero; or samples from a
file.  A bare number is shorthand for a constant signal.
"""
from __future__ import annotations

import copy
import dataclasses
import logging
import typing
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Optional

from . import _toml
from ._schema import Context, SceneError, build, field_docs, spec, suggest, to_plain
from .analysis_sections import (Analyses, EPMCAnalysis, HBMAnalysis, MasingAnalysis,  # noqa: F401
                                ModesAnalysis, QSMAAnalysis, TransientAnalysis)

__all__ = [
    "SceneError", "Scene", "load_scene", "parse_scene", "apply_overrides",
    "Signal", "Harmonic", "Joint", "Effects",
]

log = logging.getLogger(__name__)


def _signal_shorthand(raw: Any) -> Any:
    """A bare number means a constant signal."""
    if isinstance(raw, (int, float)) and not isinstance(raw, bool):
        return {"constant": raw}
    return raw


def _matrix_check(name: str, m: tuple, n: int | None = None) -> list[tuple[str, str]]:
    rows = len(m)
    if rows == 0:
        return [(name, "must be a non-empty square matrix")]
    for i, r in enumerate(m):
        if len(r) != rows:
            return [(name, f"must be square; row {i} has {len(r)} entries, expected {rows}")]
    if n is not None and rows != n:
        return [(name, f"must be {n} x {n} like model.M, got {rows} x {rows}")]
    return []


def _matrix_definiteness(name: str, m: tuple, definite: bool) -> list[tuple[str, str]]:
    """Symmetry and positive (semi-)definiteness of a square matrix (the physics of M, K, C).

    Symmetric to ``1e-10`` of its largest entry; the smallest eigenvalue must
    be positive (``definite``) or not below ``-1e-10`` of the largest (semi-definite).
    """
    import numpy as np
    a = np.asarray(m, dtype=float)
    scale = float(np.abs(a).max(initial=0.0))
    if scale == 0.0:
        return [(name, "must be positive definite, got a zero matrix")] if definite else []
    asym = float(np.abs(a - a.T).max())
    if asym > 1e-10 * scale:
        i, j = np.unravel_index(int(np.argmax(np.abs(a - a.T))), a.shape)
        return [(name, f"must be symmetric: entry [{i}][{j}] = {a[i, j]:g} but "
                       f"[{j}][{i}] = {a[j, i]:g}")]
    lam = np.linalg.eigvalsh(0.5 * (a + a.T))
    lo, hi = float(lam[0]), float(np.abs(lam).max())
    if definite and lo <= 1e-12 * hi:
        return [(name, f"must be positive definite, but its smallest eigenvalue is {lo:g}")]
    if not definite and lo < -1e-10 * hi:
        return [(name, f"must be positive semi-definite, but its smallest eigenvalue is "
                       f"{lo:g}")]
    return []


# --------------------------------------------------------------------------
# Signals
# --------------------------------------------------------------------------
@dataclass(frozen=True, kw_only=True)
class Harmonic:
    """One harmonic of a :class:`Signal`: ``cos*cos(h w t) + sin*sin(h w t)``."""

    h: int = spec(doc="harmonic number (multiple of the base frequency)", ge=1)
    cos: float = spec(0.0, doc="cosine coefficient", unit="signal unit")
    sin: float = spec(0.0, doc="sine coefficient", unit="signal unit")


@dataclass(frozen=True, kw_only=True)
class Signal:
    """A periodic input ``s(t) = constant + sum(cos_h cos(h w t) + sin_h sin(h w t))``.

    With ``clip_at_zero`` the result is ``max(0, s(t))``.  With ``file`` the
    samples come from a two-column text file (time [s] over one period, value),
    interpolated periodically; ``constant`` and ``harmonics`` must then be absent.
    """

    constant: float = spec(0.0, doc="constant part", unit="signal unit")
    harmonics: tuple[Harmonic, ...] = spec((), doc="array of {h, cos, sin} tables")
    clip_at_zero: bool = spec(False, doc="clip the signal at zero from below")
    file: Optional[str] = spec(None, doc="two-column text file (t [s], value) over one period",
                               path=True)

    def check(self):
        if self.file is not None and (self.constant != 0.0 or self.harmonics):
            return [("file", "cannot be combined with constant or harmonics")]
        return []

    @property
    def max_harmonic(self) -> int:
        return max((h.h for h in self.harmonics), default=0)


# --------------------------------------------------------------------------
# Models
# --------------------------------------------------------------------------
UNITS = ("SI", "nondimensional")


@dataclass(frozen=True, kw_only=True)
class PrescribedModel:
    """One contact element driven by a prescribed tangential motion and normal load."""

    kind: str = spec("prescribed", choices=("prescribed",))
    u_t: Signal = spec(doc="tangential displacement u_t(t): a signal table or a number",
                       unit="m",
                       coerce=_signal_shorthand)
    N: Signal = spec(doc="normal load N(t): a signal table or a number", unit="N",
                     coerce=_signal_shorthand)
    omega: float = spec(doc="base angular frequency", unit="rad/s", gt=0)
    n_periods: int = spec(3, doc="periods marched from rest; the last one is reported",
                          ge=2, le=10_000)
    n_samples: int = spec(1024, doc="samples per period", ge=8, le=10_000_000)
    area: float = spec(1.0, doc="contact area of the element", unit="m^2", gt=0)
    units: str = spec("nondimensional", choices=UNITS,
                      doc="'SI' or 'nondimensional' (consistent units)")


@dataclass(frozen=True, kw_only=True)
class LumpedContact:
    """A contact element of a lumped model.

    Tangential slip ``u_t = x[t_dof] - x[t_ref]`` and, for coupled normal load,
    normal gap ``g = gap0 + n_sign (x[n_dof] - x[n_ref])``, negative in contact.
    A reference of -1 is ground.  ``n_sign = -1`` is for a normal coordinate that
    is positive *into* contact (the gap closes as ``x[n_dof]`` grows), so the
    model needs no rewriting with sign-flipped DOFs and negated loads.

    Units: with ``area = 1`` (the default) the joint's per-area stiffnesses
    ``kt``, ``kn`` [N/m^3] act as plain springs [N/m] (in a nondimensional
    scene: force per length), and ``N0`` is a force.
    """

    t_dof: int = spec(doc="DOF index (0-based) of the tangential motion", ge=0)
    t_ref: int = spec(-1, doc="DOF index the slip is measured against (-1: ground)", ge=-1)
    n_dof: int = spec(-1, doc="DOF index of the normal gap (-1: none)", ge=-1)
    n_ref: int = spec(-1, doc="DOF index the gap is measured against (-1: ground)", ge=-1)
    n_sign: int = spec(1, choices=(1, -1),
                       doc="normal direction: g = gap0 + n_sign (x[n_dof] - x[n_ref]); "
                           "1: x[n_dof] positive away from contact (opens the gap), "
                           "-1: positive into contact (closes it)")
    gap0: float = spec(0.0, doc="normal gap at x = 0 (negative: interference)", unit="m")
    N0: Optional[float] = spec(None, doc="normal load used when effects.normal = 'fixed'",
                               unit="N", ge=0)
    area: float = spec(1.0, doc="contact area; with the default 1 the joint's kt and kn "
                                "[N/m^3] read as plain springs [N/m] (nondimensional: "
                                "force/length)", unit="m^2", gt=0)

    def check(self):
        if self.t_ref == self.t_dof:
            return [("t_ref", "must differ from t_dof")]
        if self.n_dof >= 0 and self.n_ref == self.n_dof:
            return [("n_ref", "must differ from n_dof")]
        return []


@dataclass(frozen=True, kw_only=True)
class LumpedModel:
    """Mass, stiffness and damping matrices plus contact elements between DOFs."""

    kind: str = spec("lumped", choices=("lumped",))
    M: tuple[tuple[float, ...], ...] = spec(doc="mass matrix (n x n)", unit="kg")
    K: tuple[tuple[float, ...], ...] = spec(doc="stiffness matrix (n x n)", unit="N/m")
    C: Optional[tuple[tuple[float, ...], ...]] = spec(
        None, doc="viscous damping matrix (n x n); default zero", unit="N s/m")
    contacts: tuple[LumpedContact, ...] = spec((), doc="array of contact-element tables")
    units: str = spec("SI", choices=UNITS)

    @property
    def n_dof(self) -> int:
        return len(self.M)

    def check(self):
        errs = _matrix_check("M", self.M) or _matrix_check("K", self.K, len(self.M))
        if not errs and self.C is not None:
            errs = _matrix_check("C", self.C, len(self.M))
        if errs:
            return errs
        errs = (_matrix_definiteness("M", self.M, True)
                or _matrix_definiteness("K", self.K, False)
                or (self.C is not None and _matrix_definiteness("C", self.C, False)) or [])
        if errs:
            return errs
        n = len(self.M)
        for i, c in enumerate(self.contacts):
            for name in ("t_dof", "t_ref", "n_dof", "n_ref"):
                if getattr(c, name) >= n:
                    return [(f"contacts[{i}].{name}",
                             f"must be < {n} (the model has {n} DOFs), got {getattr(c, name)}")]
        return []


@dataclass(frozen=True, kw_only=True)
class Bolt:
    """A bolt of the FE lap joint: an axial spring between two tagged mesh nodes
    plus a clamping preload (bolt-load procedure: the preload is exact in the
    preload state; the spring acts on changes of length afterwards)."""

    tag: str = spec(doc="mesh point sets '<tag>_lower' and '<tag>_upper' are the bolt's "
                        "two ends (e.g. 'bolt1')")
    preload: float = spec(12e3, doc="clamping force", unit="N", ge=0)
    stiffness: float = spec(2.0e8, doc="axial spring stiffness of the bolt", unit="N/m", gt=0)


@dataclass(frozen=True, kw_only=True)
class FEModel:
    """The 2D plane-stress lap joint built from a tagged mesh with scikit-fem,
    preloaded and reduced by Craig-Bampton (see the README)."""

    kind: str = spec("fe", choices=("fe",))
    mesh: Optional[str] = spec(None, doc="tagged mesh file readable by meshio (gmsh .msh), "
                                         "relative to the scene; or give model.dx_lap "
                                         "(and dx_full, ny_half) to generate the lap joint",
                               path=True)
    dx_lap: Optional[float] = spec(
        None, doc="generate the lap-joint mesh (instead of model.mesh) with this element "
                  "length along the lap; the bolt positions must fall on nodes (default "
                  "mesh: 0.01)", unit="m", gt=0)
    dx_full: Optional[float] = spec(
        None, doc="generated mesh: element length along the full sections (default 0.02)",
        unit="m", gt=0)
    ny_half: Optional[int] = spec(
        None, doc="generated mesh: elements through the half thickness (default 2)", ge=1)
    contact_points: str = spec(
        "nodes", choices=("nodes", "gauss"),
        doc="contact elements: 'nodes' (node-to-node pairs, consistent nodal areas) or "
            "'gauss' (model.contact_gauss Gauss points per interface edge, displacements "
            "interpolated with the edge shape functions; docs/fe.md)")
    contact_gauss: int = spec(2, doc="Gauss points per interface edge with "
                                     "contact_points = 'gauss' (2: every analysis runs; 3 and "
                                     "more integrate the stuck interface stiffness of the "
                                     "quadratic edges exactly, but their contact coordinates "
                                     "are linearly dependent, which harmonic balance and EPMC "
                                     "refuse)", ge=1, le=6)
    E: float = spec(200e9, doc="Young's modulus", unit="Pa", gt=0)
    nu: float = spec(0.29, doc="Poisson's ratio", ge=0, lt=0.5)
    rho: float = spec(7800.0, doc="density", unit="kg/m^3", gt=0)
    thickness: float = spec(0.0254, doc="out-of-plane depth (plane stress)", unit="m", gt=0)
    bolts: tuple[Bolt, ...] = spec((), doc="array of bolt tables")
    bolt_washer_radius: Optional[float] = spec(
        None, doc="bolt ends as washer patches of this half-width (the bolt spring and "
                  "preload act on the uniform-pressure weighted average of the surface "
                  "nodes under the washer, RBE3-like) instead of point loads on the tagged "
                  "nodes; converges under refinement where point bolts do not (docs/fe.md)",
        unit="m", gt=0)
    suspension_stiffness: float = spec(
        1.0e3, doc="stiffness of each soft suspension spring (x and y at every mesh point "
                   "set named 'suspension*')", unit="N/m", gt=0)
    interface_lower: str = spec("interface_lower", doc="mesh edge set of the interface's "
                                                       "lower side")
    interface_upper: str = spec("interface_upper", doc="mesh edge set of the interface's "
                                                       "upper side")
    retain_points: tuple[str, ...] = spec(
        ("excitation", "response"), doc="mesh point sets whose x and y DOFs Craig-Bampton "
                                        "keeps (besides the interface and bolt DOFs)")
    n_modes: int = spec(30, doc="fixed-interface modes kept by Craig-Bampton", ge=0)
    preload_tangential: str = spec(
        "stuck", choices=("stuck", "frictionless"),
        doc="tangential state of the interface during the preload solve")
    preload_tol: float = spec(1e-10, doc="relative residual tolerance of the preload solve",
                              gt=0, lt=1e-2)
    units: str = spec("SI", choices=("SI",))

    #: generation parameters used when only some of them are given
    GENERATE_DEFAULTS = {"dx_lap": 0.010, "dx_full": 0.020, "ny_half": 2}

    @property
    def generate(self) -> dict | None:
        """Lap-joint mesh generation parameters, or None when ``mesh`` is a file."""
        given = {k: getattr(self, k) for k in self.GENERATE_DEFAULTS}
        if all(v is None for v in given.values()):
            return None
        return {k: (self.GENERATE_DEFAULTS[k] if v is None else v) for k, v in given.items()}

    def check(self):
        given = [k for k in self.GENERATE_DEFAULTS if getattr(self, k) is not None]
        if self.mesh and given:
            return [(given[0], "cannot be given together with model.mesh: give either a mesh "
                               "file or the generation parameters (dx_lap, dx_full, ny_half); "
                               "to override a scene's mesh, also set model.mesh = ''")]
        if not self.mesh and not given:
            return [("mesh", "is required: a mesh file, or model.dx_lap (and dx_full, "
                             "ny_half) to generate the lap joint")]
        if self.bolt_washer_radius is not None and not self.bolts:
            return [("bolt_washer_radius", "is meaningless without model.bolts")]
        return []


@dataclass(frozen=True, kw_only=True)
class ROMModel:
    """A reduced model brought from elsewhere (.npz, .mat or HDF5; see the README)."""

    kind: str = spec("rom", choices=("rom",))
    file: str = spec(doc="reduced model file (.npz, .mat, .h5)", path=True)
    preload_tangential: str = spec(
        "stuck", choices=("stuck", "frictionless"),
        doc="tangential state of the interface during the preload solve")
    preload_tol: float = spec(1e-10, doc="relative residual tolerance of the preload solve",
                              gt=0, lt=1e-2)
    units: str = spec("SI", choices=UNITS)


MODEL_KINDS = {"prescribed": PrescribedModel, "lumped": LumpedModel,
               "fe": FEModel, "rom": ROMModel}


# --------------------------------------------------------------------------
# Joint, effects, damping, excitation
# --------------------------------------------------------------------------
@dataclass(frozen=True, kw_only=True)
class Joint:
    """Contact law and its parameters.

    Stiffnesses are per unit area (N/m^3) so that FE interfaces with tributary
    areas are consistent; for lumped and prescribed scenes the element area
    defaults to 1, so they read as N/m.
    """

    law: str = spec("jenkins", choices=("jenkins", "iwan4", "stuck"),
                    doc="tangential law")
    reversal: str = spec("anchor", choices=("anchor", "scaled", "manifold"),
                         doc="'anchor': physical elastic dry friction; 'scaled': reversal "
                             "force scaled by N(t)/N_r (seed Eq. 7, condition 5); "
                             "'manifold': Eq. 7's scaling with Masing's memory rule (on the "
                             "Masing manifold, seed Eq. 7 with its friction limit, to round-off; "
                             "all analyses, HBM/EPMC through its AFT kernel)")
    closing: str = spec("sample", choices=("sample", "interpolated"),
                        doc="harmonic balance (AFT) with the anchored law and a separating "
                            "contact: where a slider takes its anchor when the contact closes "
                            "between two samples, and how the interval in which it opens is "
                            "integrated; 'sample': at the last open sample, plain samples; "
                            "'interpolated': at the closing instant, and the force integrated "
                            "up to the opening instant (both linear in the gap), so the "
                            "residual is continuous when a closing or an opening instant "
                            "crosses a sample (README: Hard cases, closing and opening "
                            "instants)")
    mu: float = spec(0.1, doc="friction coefficient", ge=0)
    kt: float = spec(1.0, doc="tangential stiffness per unit area; lumped and prescribed "
                              "models: area defaults to 1, so kt is a plain spring [N/m, "
                              "or force/length when nondimensional]", unit="N/m^3", gt=0)
    kn: float = spec(1.0, doc="normal stiffness per unit area; lumped and prescribed "
                              "models: area defaults to 1, so kn is a plain spring [N/m, "
                              "or force/length when nondimensional]", unit="N/m^3", gt=0)
    chi: float = spec(-0.5, doc="Iwan exponent of the slider density", gt=-1, le=1)
    beta: float = spec(0.1, doc="Iwan ratio of the macroslip spike to the power-law part",
                       ge=0)
    n_sliders: Optional[int] = spec(
        None, doc="Iwan sliders per element; default: the fewest (geometric spacing) whose "
                  "dissipation per cycle is within joint.iwan_rtol of Segalman's closed form "
                  "from 0.01 phi_max to macroslip (uniform spacing: 40)", ge=2, le=10_000)
    iwan_spacing: str = spec("geometric", choices=("geometric", "uniform"),
                             doc="Iwan slider bins: 'geometric' (resolves deep microslip) or "
                                 "'uniform' (equal width in slip displacement)")
    iwan_rtol: float = spec(0.01, doc="Iwan dissipation accuracy that sets the default slider "
                                      "count (geometric spacing)", gt=0, lt=1)
    kt_pressure: Optional[float] = spec(
        None, doc="FE and ROM models: tangential stiffness proportional to the preload "
                  "pressure, kt A p0 / kt_pressure per element (kt is the stiffness per unit "
                  "area at the pressure kt_pressure), so that the stuck stiffness vanishes "
                  "continuously at the edge of the contact patch; p0 = N0 / A from the "
                  "model's own preload (docs/fe.md, 'Pressure-dependent contact stiffness'); default: "
                  "uniform kt A", unit="Pa", gt=0)
    kn_pressure: Optional[float] = spec(
        None, doc="FE and ROM models: normal stiffness proportional to the preload pressure, "
                  "kn A p0 / kn_pressure per element (the tangent at the preload of a rough "
                  "interface whose stiffness is proportional to its pressure), with the "
                  "initial gap that keeps N0 at the preload: the stuck normal stiffness "
                  "vanishes continuously at the patch edge (docs/fe.md, 'Pressure-dependent "
                  "kt'); default: uniform kn A", unit="Pa", gt=0)


@dataclass(frozen=True, kw_only=True)
class Effects:
    """Which physics exist; everything else is not computed."""

    normal: str = spec("fixed", choices=("fixed", "coupled"),
                       doc="'fixed': N is given (prescribed signal or preload, constant); "
                           "'coupled': N = kn A max(0, -g) from the normal gap")
    separation: bool = spec(True, doc="unilateral normal contact (N -> 0 when the gap opens); "
                                      "false makes the normal spring bilateral")
    friction: bool = spec(True, doc="tangential contact force; false: frictionless")


@dataclass(frozen=True, kw_only=True)
class Damping:
    """Linear damping added to the structure (lumped models may give C instead)."""

    kind: str = spec("none", choices=("none", "rayleigh", "modal"),
                     doc="'rayleigh': C = alpha M + beta K; 'modal': zeta per mode")
    alpha: float = spec(0.0, doc="mass-proportional Rayleigh coefficient", unit="1/s", ge=0)
    beta: float = spec(0.0, doc="stiffness-proportional Rayleigh coefficient", unit="s", ge=0)
    zeta: tuple[float, ...] = spec((), doc="modal damping ratios, in mode order", ge=0)


@dataclass(frozen=True, kw_only=True)
class Load:
    """A harmonic (plus static) force on one DOF or on a named point of the mesh."""

    force: Signal = spec(doc="force: a signal table or a number", unit="N",
                         coerce=_signal_shorthand)
    dof: int = spec(-1, doc="DOF index (lumped and ROM models)", ge=-1)
    point: str = spec("", doc="named mesh point (FE models), e.g. 'excitation'")
    direction: str = spec("y", choices=("x", "y"), doc="force direction at a mesh point")

    def check(self):
        if (self.dof < 0) == (self.point == ""):
            return [("dof", "give exactly one of dof (lumped/ROM) or point (FE)")]
        return []


@dataclass(frozen=True, kw_only=True)
class Excitation:
    loads: tuple[Load, ...] = spec((), doc="array of load tables")


@dataclass(frozen=True, kw_only=True)
class Meta:
    name: str = spec("", doc="short name of the scene")
    description: str = spec("", doc="what the scene is for")


# --------------------------------------------------------------------------
# The scene
# --------------------------------------------------------------------------
@dataclass(frozen=True, kw_only=True)
class Scene:
    """A validated scene.

    Attributes
    ----------
    model : PrescribedModel | LumpedModel | FEModel | ROMModel
    joint, effects, damping, excitation, analysis : section dataclasses
    path : pathlib.Path
        The scene file; relative paths inside it resolve against its folder.
    text : str
        The resolved scene (defaults and overrides applied) as TOML.
    """

    model: Any
    joint: Joint
    effects: Effects
    damping: Damping
    excitation: Excitation
    analysis: Analyses
    scene: Meta
    path: Path
    text: str = dataclasses.field(repr=False)

    @property
    def base_dir(self) -> Path:
        return self.path.parent

    def resolve(self, relative: str) -> Path:
        """Absolute path of a file named in the scene (relative to the scene file)."""
        return (self.base_dir / relative).resolve()

    def kernels(self):
        """The contact kernels this scene selects (see :mod:`jointsim.contact.select`)."""
        from .contact.select import select_kernels
        return select_kernels(self)


SECTIONS = {"scene": Meta, "joint": Joint, "effects": Effects, "damping": Damping,
            "excitation": Excitation, "analysis": Analyses}


def parse_value(text: str) -> Any:
    """Parse an override value as TOML, falling back to a bare string."""
    try:
        return _toml.loads(f"v = {text}")["v"]
    except _toml.TOMLDecodeError:
        return text


def apply_overrides(data: dict, overrides: list[str] | tuple[str, ...], file: str) -> dict:
    """Return a copy of ``data`` with ``key=value`` overrides applied.

    Keys are dotted; an integer part indexes an array of tables
    (``model.contacts.0.N0=2``).  Intermediate tables are created as needed;
    whether the final key is valid is checked by the scene validation.
    """
    out = copy.deepcopy(data)
    for item in overrides:
        if "=" not in item:
            raise SceneError(file, item, "override must look like key=value (from --set)")
        key, value = item.split("=", 1)
        key = key.strip()
        parts = key.split(".")
        if not key or any(p == "" for p in parts):
            raise SceneError(file, key, "is not a valid dotted key (from --set)")
        node: Any = out
        for i, p in enumerate(parts[:-1]):
            where = ".".join(parts[: i + 1])
            if isinstance(node, list):
                if not p.isdigit() or int(p) >= len(node):
                    raise SceneError(file, where, f"index {p!r} is out of range (from --set)")
                node = node[int(p)]
            else:
                nxt = node.setdefault(p, {})
                if not isinstance(nxt, (dict, list)):
                    raise SceneError(file, where, "is a value, not a table (from --set)")
                node = nxt
        last = parts[-1]
        if isinstance(node, list):
            if not last.isdigit() or int(last) >= len(node):
                raise SceneError(file, key, "index is out of range (from --set)")
            node[int(last)] = parse_value(value)
        else:
            node[last] = parse_value(value)
    return out


def parse_scene(data: dict, file: str = "<scene>", base_dir: Path | None = None) -> Scene:
    """Validate a raw scene table and return a :class:`Scene`.

    Parameters
    ----------
    data : dict
        Parsed TOML (overrides already applied).
    file : str
        Name used in error messages.
    base_dir : Path, optional
        Folder that relative paths resolve against (default: the file's folder).
    """
    path = Path(file)
    ctx = Context(file, base_dir if base_dir is not None else path.parent)
    allowed = ["model", *SECTIONS]
    for key in data:
        if key not in allowed:
            close = suggest(key, allowed)
            hint = f" (did you mean {close[0]!r}?)" if close else ""
            raise ctx.error(key, f"is not a known section{hint}; known: {', '.join(allowed)}")
    if "model" not in data:
        raise ctx.error("model", "is required but missing")
    model_raw = data["model"]
    if not isinstance(model_raw, dict):
        raise ctx.error("model", "must be a table")
    kind = model_raw.get("kind")
    if kind not in MODEL_KINDS:
        raise ctx.error("model.kind", f"must be one of {', '.join(map(repr, MODEL_KINDS))}, "
                                      f"got {kind!r}")
    model = build(MODEL_KINDS[kind], model_raw, "model", ctx)
    sections = {}
    for name, cls in SECTIONS.items():
        sections[name] = build(cls, data.get(name, {}), name, ctx)
    resolved = {"model": to_plain(model)}
    resolved.update({name: to_plain(sec) for name, sec in sections.items()})
    scene = Scene(model=model, joint=sections["joint"], effects=sections["effects"],
                  damping=sections["damping"], excitation=sections["excitation"],
                  analysis=sections["analysis"], scene=sections["scene"], path=path,
                  text=_toml.dumps(resolved))
    _check_cross(scene, ctx)
    _check_inputs(scene, ctx)
    scene.kernels()  # unsupported physics combinations fail here, before any work
    return scene


def _check_cross(scene: Scene, ctx: Context) -> None:
    """Checks that involve several sections."""
    m = scene.model
    if isinstance(m, LumpedModel):
        if not m.contacts and scene.effects.friction:
            log.info("%s: lumped model without contacts is linear", ctx.file)
        for i, c in enumerate(m.contacts):
            if scene.effects.normal == "fixed" and c.N0 is None:
                raise ctx.error(f"model.contacts[{i}].N0",
                                "is required when effects.normal = 'fixed'")
            if scene.effects.normal == "coupled" and c.n_dof < 0:
                raise ctx.error(f"model.contacts[{i}].n_dof",
                                "is required when effects.normal = 'coupled'")
    for i, load in enumerate(scene.excitation.loads):
        if isinstance(m, (LumpedModel,)) and load.dof >= m.n_dof:
            raise ctx.error(f"excitation.loads[{i}].dof",
                            f"must be < {m.n_dof} (the model has {m.n_dof} DOFs)")
        if isinstance(m, (LumpedModel, ROMModel)) and load.dof < 0:
            raise ctx.error(f"excitation.loads[{i}].dof", "is required for this model kind")
        if isinstance(m, FEModel) and not load.point:
            raise ctx.error(f"excitation.loads[{i}].point", "is required for an FE model")
    j = scene.joint
    if j.closing == "interpolated" and (
            j.reversal != "anchor" or j.law == "stuck" or not scene.effects.friction
            or scene.effects.normal != "coupled" or not scene.effects.separation):
        raise ctx.error("joint.closing",
                        "'interpolated' applies to the anchored slider laws (joint.law "
                        "'jenkins' or 'iwan4', joint.reversal = 'anchor') with friction and "
                        "a coupled, separating contact (effects.normal = 'coupled', "
                        "effects.separation = true); this scene has none of those contacts")
    for key in ("kt_pressure", "kn_pressure"):
        if getattr(j, key) is not None and not isinstance(m, (FEModel, ROMModel)):
            raise ctx.error(f"joint.{key}",
                            "applies to models with a bolt preload (model.kind 'fe' or "
                            f"'rom'), whose preload pressure N0 / A sets each element's "
                            f"{key[:2]}")
    a = scene.analysis
    for name in ("hbm", "epmc"):
        sec = getattr(a, name)
        if sec is not None:
            if 1 not in sec.harmonics:
                raise ctx.error(f"analysis.{name}.harmonics", "must include harmonic 1")
            if len(set(sec.harmonics)) != len(sec.harmonics):
                raise ctx.error(f"analysis.{name}.harmonics", "must not repeat a harmonic")
            hmax = max(sec.harmonics)
            if sec.n_samples < 2 * hmax + 1:
                raise ctx.error(f"analysis.{name}.n_samples",
                                f"must be >= 2*max(harmonics)+1 = {2 * hmax + 1} to avoid "
                                f"aliasing, got {sec.n_samples}")
    for name in ("hbm", "epmc"):
        sec = getattr(a, name)
        if sec is None:
            continue
        if sec.step_min > sec.step_max:
            raise ctx.error(f"analysis.{name}.step_min",
                            f"must not exceed analysis.{name}.step_max")
        if sec.min_periods > sec.max_periods:
            raise ctx.error(f"analysis.{name}.min_periods",
                            f"must not exceed analysis.{name}.max_periods")
    if a.hbm is not None and a.hbm.response_point:
        if isinstance(m, LumpedModel):
            raise ctx.error("analysis.hbm.response_point",
                            "names a model point, which lumped models do not have; use "
                            "analysis.hbm.response_dof")
        if isinstance(m, FEModel) and a.hbm.response_point.split(".")[0] not in m.retain_points:
            raise ctx.error("analysis.hbm.response_point",
                            f"{a.hbm.response_point!r} is not one of model.retain_points "
                            f"({', '.join(m.retain_points)}), optionally with '.x' or '.y'")
    if a.hbm is not None and isinstance(m, LumpedModel) and a.hbm.response_dof >= m.n_dof:
        raise ctx.error("analysis.hbm.response_dof",
                        f"must be < {m.n_dof} (the model has {m.n_dof} DOFs)")
    if a.epmc is not None and a.epmc.log10_amplitude_end == a.epmc.log10_amplitude_start:
        raise ctx.error("analysis.epmc.log10_amplitude_end",
                        "must differ from log10_amplitude_start")
    if a.epmc is not None:
        lo, hi = sorted((a.epmc.log10_amplitude_start, a.epmc.log10_amplitude_end))
        for i, amp in enumerate(a.epmc.amplitudes):
            if not 10.0 ** lo <= amp <= 10.0 ** hi:
                raise ctx.error(f"analysis.epmc.amplitudes[{i}]",
                                f"= {amp:g} lies outside the branch, 10^{lo:g} .. 10^{hi:g} "
                                f"(log10_amplitude_start .. log10_amplitude_end)")
    tr = a.transient
    if tr is not None:
        if isinstance(m, PrescribedModel):
            log.info("%s: a prescribed-motion model is marched by the prescribed march, which "
                     "is exact at the samples (model.n_samples, model.n_periods); the keys of "
                     "analysis.transient do not apply", ctx.file)
        elif tr.omega > 0.0 and not scene.excitation.loads:
            raise ctx.error("analysis.transient.omega",
                            "> 0 asks for a forced steady state, but excitation.loads is "
                            "empty (omega = 0 runs a free decay)")
        if isinstance(m, LumpedModel):
            for i, d in enumerate(tr.output_dofs):
                if d >= m.n_dof:
                    raise ctx.error(f"analysis.transient.output_dofs[{i}]",
                                    f"must be < {m.n_dof} (the model has {m.n_dof} DOFs)")
            if tr.output_points:
                raise ctx.error("analysis.transient.output_points",
                                "names mesh points, which a lumped model does not have; "
                                "use output_dofs")


def _check_inputs(scene: Scene, ctx: Context) -> None:
    """Signal files readable, sampled forces only where supported, memory within reach."""
    from .signals import read_signal_file
    m = scene.model
    signals = [(f"excitation.loads[{i}].force", load.force)
               for i, load in enumerate(scene.excitation.loads)]
    if isinstance(m, PrescribedModel):
        signals += [("model.u_t", m.u_t), ("model.N", m.N)]
    for key, sig in signals:
        if sig.file is not None:
            try:
                read_signal_file(scene.resolve(sig.file))
            except (ValueError, OSError) as exc:
                raise ctx.error(f"{key}.file", f"cannot be read: {exc}") from None
    for i, load in enumerate(scene.excitation.loads):
        sig = load.force
        if sig.file is not None or sig.clip_at_zero:
            what = "file" if sig.file is not None else "clip_at_zero"
            raise ctx.error(f"excitation.loads[{i}].force.{what}",
                            "is not supported for a structural load (harmonic balance, EPMC "
                            "and the static state need its harmonic coefficients): give the "
                            "force as constant and harmonics; file and clipped signals are "
                            "for the prescribed model's u_t and N")
    from .memory import memory_estimates, memory_limit
    limit = memory_limit()
    for key, nbytes in memory_estimates(scene):
        if nbytes > limit:
            raise ctx.error(key, f"asks for about {nbytes / 1e9:.3g} GB of memory (more than "
                                 f"{limit / 1e9:.3g} GB, half of this machine's); lower it")


def load_scene(path: str | Path, overrides: list[str] | tuple[str, ...] = ()) -> Scene:
    """Read, override and validate a scene file.

    Parameters
    ----------
    path : str or Path
        TOML scene file.
    overrides : sequence of str
        ``key=value`` items, as given to ``--set``.

    Raises
    ------
    SceneError
        On any problem; the message names the file and the key.
    """
    file = str(path)
    p = Path(path)
    if not p.is_file():
        raise SceneError(file, "", "does not exist or is not a file")
    try:
        data = _toml.loads(p.read_text(encoding="utf-8"))
    except _toml.TOMLDecodeError as exc:
        raise SceneError(file, "", f"is not valid TOML: {exc}") from None
    except UnicodeDecodeError:
        raise SceneError(file, "", "is not UTF-8 text") from None
    data = apply_overrides(data, list(overrides), file)
    return parse_scene(data, file, p.parent)


def key_table() -> str:
    """Every scene key with default, unit and meaning, as markdown tables."""
    parts = [("model (kind = prescribed)", PrescribedModel, "model"),
             ("model (kind = lumped)", LumpedModel, "model"),
             ("model.contacts[] (lumped)", LumpedContact, "model.contacts[]"),
             ("model (kind = fe)", FEModel, "model"),
             ("model.bolts[] (fe)", Bolt, "model.bolts[]"),
             ("model (kind = rom)", ROMModel, "model"),
             ("signals (u_t, N, force)", Signal, "<signal>"),
             ("signal harmonics", Harmonic, "<signal>.harmonics[]"),
             ("scene", Meta, "scene"), ("joint", Joint, "joint"), ("effects", Effects, "effects"),
             ("damping", Damping, "damping"),
             ("excitation.loads[]", Load, "excitation.loads[]")]
    for f in dataclasses.fields(Analyses):
        tp = typing.get_type_hints(Analyses)[f.name]
        cls = next(a for a in typing.get_args(tp) if a is not type(None)) \
            if typing.get_origin(tp) is not None else tp
        parts.append((f"analysis.{f.name}", cls, f"analysis.{f.name}"))
    out = []
    for title, cls, prefix in parts:
        out += [f"**{title}**", "", "| key | default | unit | meaning |", "|---|---|---|---|"]
        for key, default, unit, doc in field_docs(cls, prefix, leaves=(Signal,)):
            out.append(f"| `{key}` | {default} | {unit} | {doc} |")
        out.append("")
    return "\n".join(out)
