"""dgcal: calibration of UAV photogrammetric payloads for direct georeferencing.

The public Python API is `dgcal.api` (every name of it is also an attribute of this package, imported on
first use so that the command line starts fast); the command line is `dgcal` (dgcal.cli).
"""
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
