"""Pick the contact kernels a scene needs, once, from a table.

The scene's ``joint`` and ``effects`` decide which physics exist.  This module
maps them to a tangential kernel and a normal kernel before any loop runs; a
combination that is not supported raises :class:`~jointsim.scene.SceneError`
naming the key, so no work starts.  Effects the scene leaves out are never
computed: with ``effects.normal = "fixed"`` the normal kernel is ``given``
(the normal load is an input, no gap is evaluated), and with
``effects.friction = false`` the tangential kernel is ``none``.
"""
from __future__ import annotations

from dataclasses import dataclass

from .._schema import SceneError

#: (law, reversal) -> tangential kernel, when friction is on.
TANGENTIAL_TABLE = {
    ("jenkins", "anchor"): "bank_anchor",
    ("jenkins", "scaled"): "bank_scaled",
    ("iwan4", "anchor"): "bank_anchor",
    ("iwan4", "scaled"): "bank_scaled",
    ("stuck", "anchor"): "linear",
}

#: (normal, separation) -> normal kernel.
NORMAL_TABLE = {
    ("fixed", True): "given",
    ("fixed", False): "given",
    ("coupled", True): "unilateral",
    ("coupled", False): "bilateral",
}


@dataclass(frozen=True)
class KernelChoice:
    """The kernels of a scene.

    Attributes
    ----------
    tangential : str
        ``bank_anchor``, ``bank_scaled``, ``linear`` or ``none``.
    normal : str
        ``given`` (N is an input), ``unilateral`` or ``bilateral`` penalty.
    law : str
        The scene's law name (``jenkins``, ``iwan4``, ``stuck``).
    """

    tangential: str
    normal: str
    law: str

    @property
    def coupled(self) -> bool:
        """True when N is computed from the normal gap."""
        return self.normal != "given"


def select_kernels(scene) -> KernelChoice:
    """Return the kernels for ``scene`` or raise :class:`SceneError`."""
    file = str(scene.path)
    j, fx = scene.joint, scene.effects
    kind = scene.model.kind
    if not fx.friction:
        tangential = "none"
    else:
        key = (j.law, j.reversal)
        if key not in TANGENTIAL_TABLE:
            raise SceneError(file, "joint.reversal",
                             f"{j.reversal!r} is not defined for law {j.law!r}; "
                             "'scaled' applies to the friction laws 'jenkins' and 'iwan4'")
        tangential = TANGENTIAL_TABLE[key]
    normal = NORMAL_TABLE[(fx.normal, fx.separation)]
    if kind == "prescribed":
        if normal != "given":
            raise SceneError(file, "effects.normal",
                             "must be 'fixed' for a prescribed-motion model")
        if tangential == "none":
            raise SceneError(file, "effects.friction",
                             "must be true for a prescribed-motion model: without friction "
                             "there is nothing to compute")
    return KernelChoice(tangential=tangential, normal=normal, law=j.law)
