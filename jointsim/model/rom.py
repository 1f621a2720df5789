"""Builder of ``kind = "rom"`` scenes: a reduced model read from a file, preloaded."""
from __future__ import annotations

from .._schema import SceneError
from ..io.rom import load_rom
from .preload import structural_model
from .structural import StructuralModel


def build_rom(scene) -> StructuralModel:
    """Structural model of a ``kind = "rom"`` scene (reduced model from a file; a
    builder of :data:`jointsim.model.BUILDERS`): ``source`` is the file, ``rom`` the
    reduced model read from it; ``preload`` and ``linearisation`` as for FE models.

    Raises
    ------
    SceneError
        When the file lacks an array or is inconsistent (names ``model.file``).
    """
    m = scene.model
    path = scene.resolve(m.file)
    try:
        rom = load_rom(path)
    except (KeyError, ValueError) as exc:
        raise SceneError(str(scene.path), "model.file", f"{path}: {exc}") from None
    return structural_model(scene, rom, preload_tangential=m.preload_tangential,
                            preload_tol=m.preload_tol, source=str(path))
