"""Small scenes shared by the time-marching tests, built from tables (no files)."""
from __future__ import annotations

import numpy as np

from jointsim.scene import parse_scene


def lumped(M, K, C=None, contacts=(), joint=None, effects=None, loads=(), transient=None):
    model = {"kind": "lumped", "M": M, "K": K, "contacts": list(contacts)}
    if C is not None:
        model["C"] = C
    data = {"model": model, "joint": joint or {}, "effects": effects or {},
            "excitation": {"loads": list(loads)}}
    if transient is not None:
        data["analysis"] = {"transient": transient}
    return parse_scene(data, "test.toml")


def sdof_jenkins(transient, C=0.1, F=0.5, law="jenkins", reversal="anchor"):
    """m = k = 1, Jenkins to ground with kt = 0.25 and slip force 0.2."""
    return lumped([[1.0]], [[1.0]], [[C]], contacts=[{"t_dof": 0, "N0": 1.0}],
                  joint={"law": law, "reversal": reversal, "kt": 0.25, "mu": 0.2},
                  loads=[{"dof": 0, "force": {"harmonics": [{"h": 1, "cos": F}]}}],
                  transient=transient)


def two_dof_jenkins(omega, F=0.15, transient=None, C=0.01):
    """The 2-DOF scene of issue 4: M = I, K = [[2,-1],[-1,2]], C = 0.01 I,
    Jenkins from DOF 1 to ground (kt = 0.25, slip force 0.2), F cos(w t) on DOF 0."""
    tr = {"omega": omega}
    tr.update(transient or {})
    return lumped([[1.0, 0.0], [0.0, 1.0]], [[2.0, -1.0], [-1.0, 2.0]],
                  [[C, 0.0], [0.0, C]], contacts=[{"t_dof": 1, "N0": 1.0}],
                  joint={"law": "jenkins", "kt": 0.25, "mu": 0.2},
                  loads=[{"dof": 0, "force": {"harmonics": [{"h": 1, "cos": F}]}}],
                  transient=tr)


def separating(transient, tangential=0.5):
    """DOF 0 tangential, DOF 1 normal; a constant push of 1 and a harmonic normal
    force of 1.5 open the unilateral contact for part of every period."""
    return lumped([[1.0, 0.0], [0.0, 1.0]], [[1.0, 0.0], [0.0, 0.5]],
                  [[0.05, 0.0], [0.0, 0.2]],
                  contacts=[{"t_dof": 0, "n_dof": 1, "gap0": 0.0}],
                  joint={"law": "jenkins", "kt": 2.0, "mu": 0.5, "kn": 10.0},
                  effects={"normal": "coupled", "separation": True},
                  loads=[{"dof": 1, "force": {"constant": -1.0,
                                              "harmonics": [{"h": 1, "cos": 1.5}]}},
                         {"dof": 0, "force": {"harmonics": [{"h": 1, "sin": tangential}]}}],
                  transient=transient)


def jenkins_dissipation(A, kt=0.25, Fs=0.2):
    """Loop area of a Jenkins element between two reversals A apart/2 (DESIGN §5)."""
    return 4.0 * Fs * (A - Fs / kt) if kt * A > Fs else 0.0


def jenkins_backbone(A, kt=0.25, Fs=0.2, m=1.0, k=1.0):
    """First-harmonic (describing-function) backbone of the SDOF Jenkins oscillator:
    what EPMC with harmonics {0, 1} gives.  Returns frequency [Hz] and damping ratio."""
    A = np.asarray(A, dtype=float)
    c1 = np.where(kt * A > Fs, 0.0, kt * A)
    slip = kt * A > Fs
    b = np.arccos(1.0 - 2.0 * Fs / (kt * A[slip]))
    c1[slip] = kt * A[slip] / np.pi * (b - np.sin(2.0 * b) / 2.0)
    w2 = (k + c1 / A) / m
    s1 = np.where(slip, -(4.0 * Fs / np.pi) * (1.0 - Fs / (kt * A)), 0.0)
    return np.sqrt(w2) / (2.0 * np.pi), -s1 / (2.0 * m * w2 * A)
