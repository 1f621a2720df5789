"""Pick the contact laws a scene needs, once, from a table.

The scene's ``joint`` and ``effects`` decide which physics exist.  This module
maps them to a tangential law class and a normal law class before any loop
runs; a combination that is not supported raises
:class:`~jointsim.scene.SceneError` naming the key, so no work starts.
Effects the scene leaves out are never computed: with ``effects.normal =
"fixed"`` the normal law is :class:`~jointsim.contact.normal.GivenNormal`
(the normal load is an input, no gap is evaluated), and with
``effects.friction = false`` the tangential law is
:class:`~jointsim.contact.laws.NoFriction`.

Adding a law: its class in :mod:`jointsim.contact.laws` (with its kernels),
one row in :data:`TANGENTIAL_TABLE`, and its scene parameters.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from .._schema import SceneError
from .laws import (AnchoredBank, LinearSpring, ManifoldBank, NoFriction, ScaledBank, TangentialLaw,
                   iwan4_parameters, jenkins_parameters, no_parameters, spring_parameters)
from .normal import BilateralPenalty, GivenNormal, NormalLaw, UnilateralPenalty

#: (joint.law, joint.reversal) -> (law class, slider parameters(joint, kt A, mu)),
#: when friction is on.
TANGENTIAL_TABLE: dict[tuple[str, str], tuple[type[TangentialLaw], Callable]] = {
    ("jenkins", "anchor"): (AnchoredBank, jenkins_parameters),
    ("jenkins", "scaled"): (ScaledBank, jenkins_parameters),
    ("iwan4", "anchor"): (AnchoredBank, iwan4_parameters),
    ("iwan4", "scaled"): (ScaledBank, iwan4_parameters),
    ("jenkins", "manifold"): (ManifoldBank, jenkins_parameters),
    ("iwan4", "manifold"): (ManifoldBank, iwan4_parameters),
    ("stuck", "anchor"): (LinearSpring, spring_parameters),
}

#: The tangential law when ``effects.friction = false``.
FRICTIONLESS = (NoFriction, no_parameters)

#: (effects.normal, effects.separation) -> normal law class.
NORMAL_TABLE: dict[tuple[str, bool], type[NormalLaw]] = {
    ("fixed", True): GivenNormal,
    ("fixed", False): GivenNormal,
    ("coupled", True): UnilateralPenalty,
    ("coupled", False): BilateralPenalty,
}


@dataclass(frozen=True)
class KernelChoice:
    """The contact laws of a scene, chosen once.

    Attributes
    ----------
    law_class : type of TangentialLaw
    parameters : callable
        ``parameters(joint, KT, mu) -> (k, g)``, the slider arrays.
    normal_class : type of NormalLaw
    law : str
        The scene's law name (``jenkins``, ``iwan4``, ``stuck``).
    """

    law_class: type
    parameters: Callable
    normal_class: type
    law: str

    @property
    def tangential(self) -> str:
        """Name of the tangential kernel (for messages and files)."""
        return self.law_class.name

    @property
    def normal(self) -> str:
        """Name of the normal law (for messages and files)."""
        return self.normal_class.name

    @property
    def coupled(self) -> bool:
        """True when N is computed from the normal gap."""
        return self.normal_class.coupled

    def tangential_law(self, joint, area) -> TangentialLaw:
        """Per-element tangential law.

        Parameters
        ----------
        joint : jointsim.scene.Joint
            Joint parameters (stiffness per unit area).
        area : array_like, shape (n_e,)
            Element areas [m^2].
        """
        area = np.atleast_1d(np.asarray(area, dtype=float))
        mu = np.full(area.size, joint.mu)
        k, g = self.parameters(joint, joint.kt * area, mu)
        return self.law_class(k=k, g=g, mu=mu)

    def normal_law(self, joint, area) -> NormalLaw:
        """Per-element normal law with stiffness ``kn A`` [N/m]."""
        return self.normal_class(kn=joint.kn * np.atleast_1d(np.asarray(area, dtype=float)))


def select_kernels(scene) -> KernelChoice:
    """Return the contact laws of ``scene`` or raise :class:`SceneError`."""
    file = str(scene.path)
    j, fx = scene.joint, scene.effects
    kind = scene.model.kind
    if not fx.friction:
        law_class, parameters = FRICTIONLESS
    else:
        key = (j.law, j.reversal)
        if key not in TANGENTIAL_TABLE:
            raise SceneError(file, "joint.reversal",
                             f"{j.reversal!r} is not defined for law {j.law!r}; "
                             "'scaled' and 'manifold' apply to the friction laws 'jenkins' "
                             "and 'iwan4'")
        law_class, parameters = TANGENTIAL_TABLE[key]
        if not law_class.has_aft:
            for name in ("hbm", "epmc"):
                if getattr(scene.analysis, name, None) is not None:
                    raise SceneError(file, "joint.reversal",
                                     f"{j.reversal!r} has no harmonic-balance (AFT) kernel "
                                     f"with an exact Jacobian, so analysis.{name} cannot use "
                                     "it; use a reversal law with an AFT kernel ('anchor', "
                                     "'scaled', 'manifold') or a transient analysis")
    normal_class = NORMAL_TABLE[(fx.normal, fx.separation)]
    if kind == "prescribed":
        if normal_class.coupled:
            raise SceneError(file, "effects.normal",
                             "must be 'fixed' for a prescribed-motion model")
        if not law_class.has_force:
            raise SceneError(file, "effects.friction",
                             "must be true for a prescribed-motion model: without friction "
                             "there is nothing to compute")
    return KernelChoice(law_class=law_class, parameters=parameters,
                        normal_class=normal_class, law=j.law)


def law_class(law: str, reversal: str, friction: bool = True) -> type[TangentialLaw]:
    """The law class of scene keys ``joint.law``/``joint.reversal``/``effects.friction``."""
    return TANGENTIAL_TABLE[(law, reversal)][0] if friction else FRICTIONLESS[0]


def tangential_law(law: str, reversal: str, joint, area, friction: bool = True) -> TangentialLaw:
    """The tangential law of scene keys ``joint.law``/``joint.reversal`` (table lookup).

    Parameters
    ----------
    law, reversal : str
        Scene values of ``joint.law`` and ``joint.reversal``.
    joint : jointsim.scene.Joint
    area : array_like, shape (n_e,)
        Element areas [m^2].
    friction : bool
        ``effects.friction``.
    """
    law_class, parameters = TANGENTIAL_TABLE[(law, reversal)] if friction else FRICTIONLESS
    return KernelChoice(law_class, parameters, GivenNormal, law).tangential_law(joint, area)
