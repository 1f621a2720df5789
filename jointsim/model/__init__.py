"""Structural models: linear matrices, contact elements and their static state.

Every model kind (lumped, FE, ROM) is turned into a
:class:`~jointsim.model.structural.StructuralModel` by one builder of the
explicit table :data:`BUILDERS`; solvers work on that object only.

* :mod:`~jointsim.model.structural` -- :class:`ContactSet`,
  :class:`StructuralModel` and its typed parts (:class:`Preload`,
  :class:`FEParts`); sign conventions;
* :mod:`~jointsim.model.damping` -- Rayleigh and modal damping;
* :mod:`~jointsim.model.lumped`, :mod:`~jointsim.model.fe`,
  :mod:`~jointsim.model.rom` -- the builders;
* :mod:`~jointsim.model.preload` -- a reduced model under the scene's joint
  (bolt preload, contact set), shared by the FE and ROM builders.
"""
from __future__ import annotations

import logging
from typing import Callable

from .damping import damping_matrix
from .lumped import build_lumped
from .structural import (ContactSet, FEParts, Preload, StructuralModel, fixed_normal_stiffness,
                         make_contact_set, with_fixed_normal_springs)

log = logging.getLogger(__name__)


def build_fe(scene) -> StructuralModel:
    """Structural model of a ``kind = "fe"`` scene (:func:`jointsim.model.fe.build_fe`)."""
    from .fe import build_fe as build
    return build(scene)


def build_rom(scene) -> StructuralModel:
    """Structural model of a ``kind = "rom"`` scene (:func:`jointsim.model.rom.build_rom`)."""
    from .rom import build_rom as build
    return build(scene)


#: model kind -> builder(scene) -> StructuralModel.  The FE and ROM modules
#: (scikit-fem, file formats) are imported when a model of their kind is built.
BUILDERS: dict[str, Callable] = {"lumped": build_lumped, "fe": build_fe, "rom": build_rom}


def build_model(scene) -> StructuralModel:
    """Build the structural model of a scene (lumped, FE or ROM).

    Parameters
    ----------
    scene : jointsim.scene.Scene

    Returns
    -------
    StructuralModel
        With its ``linearisation`` (and, for FE and ROM models, ``preload``).

    Raises
    ------
    NotImplementedError
        For a model kind that has no builder.
    """
    kind = scene.model.kind
    if kind not in BUILDERS:
        raise NotImplementedError(f"no structural model builder for model.kind = {kind!r}")
    model = BUILDERS[kind](scene)
    log.info("model %s: %d DOFs, %d contact elements (%s / %s kernels)", kind, model.n_dof,
             model.contacts.n_elements, model.contacts.law.name,
             model.contacts.normal.name)
    return model


__all__ = ["BUILDERS", "ContactSet", "FEParts", "Preload", "StructuralModel", "build_fe",
           "build_lumped", "build_model", "build_rom", "damping_matrix",
           "fixed_normal_stiffness", "make_contact_set", "with_fixed_normal_springs"]
