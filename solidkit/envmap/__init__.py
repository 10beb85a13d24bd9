"""The panorama core shared by every part of solidkit (conventions: docs/conventions.md).

Every public name of the sub-modules below is available here (``from solidkit.envmap import
read_exr``). They are imported on first use (PEP 562), so that a command which needs only the
coordinates does not pay for SciPy (``sun``) or OpenEXR (``io``) at start-up.
"""

import importlib
import importlib.util
from typing import Any

_SUBMODULES = ("coords", "io", "resample", "perspective", "cubemap", "sh", "sun")


def __getattr__(name: str) -> Any:
    if name == "__all__":  # ``from solidkit.envmap import *``: every public name (imports every sub-module)
        return [n for sub in _SUBMODULES for n in importlib.import_module(f"{__name__}.{sub}").__all__]
    if name.startswith("__"):
        raise AttributeError(name)
    if (
        importlib.util.find_spec(f"{__name__}.{name}") is not None
    ):  # a sub-module (``from solidkit.envmap import tilt``)
        return importlib.import_module(f"{__name__}.{name}")
    for sub in _SUBMODULES:
        module = importlib.import_module(f"{__name__}.{sub}")
        if name in module.__all__:
            value = getattr(module, name)
            globals()[name] = value
            return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__getattr__("__all__")))
