"""dgcal: calibration of UAV photogrammetric payloads for direct georeferencing.

The public Python API is `dgcal.api` (every name of it is also an attribute of this package, imported on
first use so that the command line starts fast); the command line is `dgcal` (dgcal.cli).
"""
import sys
import warnings

# pycolmap's extension carries its own zlib, and the system libz loaded as its dependency binds to that copy:
# every later zlib user (PNG writing in Pillow/matplotlib, Python's zlib) then aborts the process with heap
# corruption. Loading zlib before pycolmap keeps them apart, so dgcal loads it first thing.
if "pycolmap" in sys.modules and "zlib" not in sys.modules:
    warnings.warn("pycolmap was imported before zlib: its bundled zlib replaces the system one, and writing "
                  "PNG figures or compressed files will abort the process; import dgcal (or zlib) before "
                  "pycolmap", RuntimeWarning, stacklevel=2)
import zlib  # noqa: E402,F401  (see above)

__version__ = "0.1.0"


import importlib


def __getattr__(name: str):
    # lazy re-export of dgcal.api: `import dgcal` stays light, `dgcal.triangulate` still works
    if name.startswith("__") or name == "api":
        raise AttributeError(name)
    api = importlib.import_module("dgcal.api")
    if name in api.__all__:
        return getattr(api, name)
    raise AttributeError(f"module 'dgcal' has no attribute {name!r}")


def __dir__():
    api = importlib.import_module("dgcal.api")
    return sorted(list(globals()) + list(api.__all__))
