"""Paths and small scene builders shared by several test files (not collected).

``ROOT`` is the repository root; ``COARSE`` is the ``--set`` override that puts
a lap-joint scene on the committed coarse mesh (the scenes' mesh paths are
relative to ``models/``).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from jointsim import _toml
from jointsim.scene import apply_overrides, parse_scene

ROOT = Path(__file__).resolve().parents[1]
MODELS = ROOT / "models"
MESHES = ROOT / "meshes"
SEED = MODELS / "seed_fig3"
COUPLED = MODELS / "lap_joint_nodes.toml"
FIXED = MODELS / "lap_joint_fixed_n_nodes.toml"
CHAIN2 = MODELS / "hbm" / "chain2_jenkins.toml"
COARSE = "model.mesh='../meshes/lap_joint_coarse.msh'"


def four_dof(law="jenkins", reversal="anchor", normal="fixed", C=None):
    """Two contact elements between DOFs and to ground, gaps closed at rest."""
    C = C if C is not None else np.diag([0.01, 0.01, 0.02, 0.01]).tolist()
    d = {"model": {"kind": "lumped", "M": np.diag([1.0, 1.0, 2.0, 1.0]).tolist(),
                   "K": [[2, -1, 0, 0], [-1, 2, -0.5, 0], [0, -0.5, 1, -0.3], [0, 0, -0.3, 1]],
                   "C": C,
                   "contacts": [{"t_dof": 1, "n_dof": 2, "N0": 1.0, "gap0": -0.5},
                                {"t_dof": 0, "t_ref": 2, "n_dof": 3, "n_ref": 0, "N0": 0.8,
                                 "gap0": -0.3}]},
         "joint": {"law": law, "reversal": reversal, "mu": 0.3, "kt": 0.8, "kn": 1.0,
                   "n_sliders": 5},
         "effects": {"normal": normal, "separation": True},
         "excitation": {"loads": [{"dof": 0, "force": {"harmonics": [{"h": 1, "cos": 1.0}]}}]}}
    return parse_scene(d, "four_dof.toml")


NO_FULL = ["analysis.modes.full_model=false", "analysis.modes.monolithic=false"]


def lap_scene(path, analyses=("modes",), overrides=()):
    """A lap-joint scene on the coarse mesh keeping only the named analyses."""
    out, keep = [], True
    for line in path.read_text().splitlines():
        s = line.strip()
        if s.startswith("[") and not s.startswith("[["):
            keep = not s.startswith("[analysis.") or s[len("[analysis."):-1] in analyses
        if keep:
            out.append(line)
    data = apply_overrides(_toml.loads("\n".join(out)), [COARSE, *overrides], str(path))
    return parse_scene(data, str(path), path.parent)
