"""The finite-element lap joint: tagged meshes, plane-stress assembly, interfaces.

* :mod:`~jointsim.fem.generate` -- structured meshes of the lap joint and of beams;
* :mod:`~jointsim.fem.mesh` -- meshio files -> :class:`~jointsim.fem.mesh.FEMesh`;
* :mod:`~jointsim.fem.assembly` -- scikit-fem K and M, suspension, bolts;
* :mod:`~jointsim.fem.interface` -- node pairing, tributary areas, frames;
* :mod:`~jointsim.fem.reduction` -- Craig-Bampton reduction;
* :mod:`~jointsim.fem.reduced` -- :class:`~jointsim.fem.reduced.ReducedModel`
  and its bolt table (plain data, also read from ROM files);
* :mod:`~jointsim.fem.build` -- FE structure -> reduced model (the scene ->
  :class:`~jointsim.model.StructuralModel` builder is :mod:`jointsim.model.fe`).
"""
