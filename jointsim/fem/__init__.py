"""The finite-element lap joint: tagged meshes, plane-stress assembly, interfaces.

* :mod:`~jointsim.fem.generate` -- structured meshes of the lap joint and of beams;
* :mod:`~jointsim.fem.mesh` -- meshio files -> :class:`~jointsim.fem.mesh.FEMesh`;
* :mod:`~jointsim.fem.assembly` -- scikit-fem K and M, suspension, bolts;
* :mod:`~jointsim.fem.interface` -- node pairing, tributary areas, frames;
* :mod:`~jointsim.fem.build` -- scene -> reduced :class:`~jointsim.model.StructuralModel`
  (registered as ``BUILDERS["fe"]`` by :mod:`jointsim.reduction`).
"""
