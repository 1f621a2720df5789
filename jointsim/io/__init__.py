"""Result files (HDF5) and mesh export."""
from .hdf5 import SCHEMA_VERSION, ResultWriter, read_attrs, unit
from .loops import write_loops

__all__ = ["SCHEMA_VERSION", "ResultWriter", "read_attrs", "unit", "write_loops"]
