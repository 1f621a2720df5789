"""Model building: the builder table, the typed fields of every kind, no import cycle."""
import ast
import dataclasses
from pathlib import Path

import numpy as np
import pytest

from jointsim.fem.reduced import ReducedModel
from jointsim.fem.reduction import CraigBampton
from jointsim.io.rom import save_rom
from jointsim.model import BUILDERS, FEParts, Preload, StructuralModel, build_model
from jointsim.scene import load_scene, parse_scene
from jointsim.solvers.static import StaticResult, StuckLinearisation, stuck_linearisation

from .._scenes import ROOT

FE_SCENE = ROOT / "models" / "lap_joint_fixed_n_nodes.toml"


@pytest.fixture
def fe_model(coarse_fixed_model):
    return coarse_fixed_model


def test_builder_table_is_explicit():
    assert set(BUILDERS) == {"lumped", "fe", "rom"}
    assert all(callable(b) for b in BUILDERS.values())


def test_lumped_model_has_its_linearisation_and_no_preload():
    d = {"model": {"kind": "lumped", "M": [[1.0, 0.0], [0.0, 1.0]],
                   "K": [[2.0, -1.0], [-1.0, 2.0]], "contacts": [{"t_dof": 1, "N0": 10.0}]},
         "joint": {"law": "jenkins", "kt": 0.25, "mu": 0.5},
         "excitation": {"loads": [{"dof": 0, "force": {"constant": 0.3}}]}}
    m = build_model(parse_scene(d, "lumped.toml"))
    assert isinstance(m, StructuralModel)
    assert m.preload is None and m.fe is None and m.rom is None and m.source is None
    lin = m.linearisation
    assert isinstance(lin, StuckLinearisation) and lin.source == "solved"
    assert lin.x0.shape == (2,) and lin.K.shape == (2, 2)
    assert not hasattr(m, "extra")
    with pytest.raises(dataclasses.FrozenInstanceError):
        m.linearisation = None
    # the one definition, computed once with the model
    again = stuck_linearisation(m)
    np.testing.assert_array_equal(again.x0, lin.x0)
    assert abs(again.K - lin.K).max() == 0.0


def test_fe_model_has_typed_preload_fe_parts_and_rom(fe_model):
    m = fe_model
    assert isinstance(m.preload, Preload)
    assert isinstance(m.preload.result, StaticResult) and m.preload.result.convergence.success
    np.testing.assert_array_equal(m.preload.x0, m.preload.result.x)
    assert m.preload.f_clamp.shape == (m.n_dof,) and m.preload.K_bolt.shape == m.K.shape
    assert m.preload.time_s >= 0.0
    assert isinstance(m.fe, FEParts) and isinstance(m.fe.cb, CraigBampton)
    assert m.fe.mesh_file.endswith("lap_joint_coarse.msh")
    assert m.fe.n_full_dof == m.fe.structure.n_dof > m.n_dof
    assert m.fe.cb.T.shape == (m.fe.n_full_dof, m.n_dof)
    assert isinstance(m.rom, ReducedModel) and m.rom.n_dof == m.n_dof
    assert m.source is None
    assert m.linearisation.source == "model"
    np.testing.assert_array_equal(m.linearisation.x0, m.preload.x0)


def test_rom_model_from_a_saved_file(tmp_path, fe_model):
    path = save_rom(tmp_path / "rom.npz", fe_model.rom)
    scene = load_scene(FE_SCENE, ["model={kind='rom', file='" + str(path) + "'}",
                                  "excitation.loads.0.point=''",
                                  f"excitation.loads.0.dof={fe_model.points['excitation']}"])
    m = build_model(scene)
    assert m.source == str(path) and m.fe is None
    assert isinstance(m.rom, ReducedModel) and isinstance(m.preload, Preload)
    assert m.linearisation.source == "model"
    np.testing.assert_allclose(m.preload.x0, fe_model.preload.x0, rtol=0,
                               atol=1e-9 * np.abs(fe_model.preload.x0).max())


# --------------------------------------------------------------------------
# No import cycle inside jointsim/
# --------------------------------------------------------------------------
def _module_graph(root: Path) -> dict:
    """Module -> modules of the package it imports (any import statement, also
    inside functions), from the AST of every file under ``root``."""
    mods = {}
    for f in root.rglob("*.py"):
        parts = list(f.relative_to(root.parent).with_suffix("").parts)
        is_pkg = parts[-1] == "__init__"
        mods[".".join(parts[:-1] if is_pkg else parts)] = (f, is_pkg)
    graph = {}
    for name, (f, is_pkg) in mods.items():
        here = name.split(".") if is_pkg else name.split(".")[:-1]
        edges = set()
        for node in ast.walk(ast.parse(f.read_text())):
            if isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                base = (".".join(here[:len(here) - node.level + 1] +
                                 ([node.module] if node.module else []))
                        if node.level else node.module)
                targets = [f"{base}.{a.name}" if f"{base}.{a.name}" in mods else base
                           for a in node.names]
            else:
                continue
            for t in targets:
                while t and t not in mods:
                    t = t.rpartition(".")[0]
                if t and t != name:
                    edges.add(t)
        graph[name] = edges
    return graph


def _cycles(graph: dict) -> list:
    """Strongly connected components with more than one module (Tarjan)."""
    index, low, stack, on, out = {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in graph[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = set()
            while True:
                w = stack.pop()
                on.discard(w)
                comp.add(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(frozenset(comp))

    for v in graph:
        if v not in index:
            visit(v)
    return out


def test_no_import_cycle():
    graph = _module_graph(ROOT / "jointsim")
    assert "jointsim.model.fe" in graph and "jointsim.fem.reduction" in graph
    found = _cycles(graph)
    assert not found, [sorted(c) for c in found]
