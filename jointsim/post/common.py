"""Helpers shared by the plotters and tables."""
from __future__ import annotations

from pathlib import Path

from ..io.hdf5 import unit


def pyplot():
    """matplotlib.pyplot with the non-interactive backend (imported lazily)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    return plt


def quantity_label(symbol: str, quantity: str, units: str) -> str:
    """Axis label ``symbol [unit]``."""
    return f"{symbol} [{unit(quantity, units)}]"


def scene_from_file(h5):
    """The resolved scene stored in a result file."""
    from .. import _toml
    from ..scene import parse_scene
    path = Path(h5.attrs.get("scene_path", "<stored scene>"))
    data = _toml.loads(h5.attrs["scene"])
    return parse_scene(data, str(path), path.parent)


def law_from_file(h5, n_elements: int | None = None):
    """The tangential law of the elements of a result file.

    From ``/contacts/mu``, ``/contacts/k``, ``/contacts/g`` and the ``law``,
    ``reversal`` and ``friction`` attributes of ``/contacts`` when the file has them (written by
    :func:`jointsim.analyses.modes.write_model_tables`).  Older files (and
    prescribed-motion ones): rebuilt from the stored scene and the element
    areas in ``/contacts/area`` (area 1 per element when absent: prescribed
    and lumped scenes with default areas).
    """
    import numpy as np

    from ..contact import law_class
    if all(f"contacts/{k}" in h5 for k in ("mu", "k", "g")) \
            and "friction" in h5["contacts"].attrs:
        a = h5["contacts"].attrs
        cls = law_class(str(a["law"]), str(a["reversal"]), bool(a["friction"]))
        return cls(h5["contacts/k"][()], h5["contacts/g"][()], h5["contacts/mu"][()])
    scene = scene_from_file(h5)
    k = scene.kernels()
    if "contacts/area" in h5:
        area = h5["contacts/area"][()]
    elif scene.model.kind == "prescribed":
        area = np.array([scene.model.area])
    else:
        area = np.ones(n_elements or h5["loops/u"].shape[1])
    return k.tangential_law(scene.joint, area)


def backbone_rows(a, f, z, n_rows: int = 8, indent: str = "    ") -> list[str]:
    """A few rows of an amplitude / frequency / damping table, evenly spread."""
    import numpy as np
    idx = np.unique(np.linspace(0, a.size - 1, min(a.size, n_rows)).astype(int))
    lines = [f"{indent}{'amplitude':>12} {'freq [Hz]':>12} {'zeta':>10}"]
    lines += [f"{indent}{a[i]:>12.4g} {f[i]:>12.6g} {z[i]:>10.4g}" for i in idx]
    return lines


def backbone_section(h5, group: str, label: str) -> str:
    """``jointsim info`` section of an amplitude-dependent backbone (EPMC, QSMA)."""
    import numpy as np
    g = h5[group]
    lines = [f"  {label} mode {g.attrs.get('mode', '?')}: linear "
             f"{float(g.attrs.get('linear_frequency_hz', np.nan)):.6g} Hz; "
             f"{g.attrs.get('message', '')}"]
    if all(k in g for k in ("amplitude", "frequency_hz", "damping_ratio")) \
            and g["amplitude"].shape[0]:  # an interrupted run may hold only some
        lines += backbone_rows(g["amplitude"][()], g["frequency_hz"][()],
                               g["damping_ratio"][()])
    return "\n".join(lines)
