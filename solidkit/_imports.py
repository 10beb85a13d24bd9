"""Import order for native libraries, fixed in one place.

Measured trap: importing ``pycolmap`` before ``cv2`` makes cv2's PNG writer abort
(``free(): invalid pointer``). ``solidkit/__init__`` imports this module first, so cv2 is
always loaded before anything can load pycolmap. Modules that need pycolmap import it via
:func:`pycolmap` below, never directly.
"""

import cv2  # noqa: F401  (must precede pycolmap)


def pycolmap():
    """Return the ``pycolmap`` module, imported after cv2."""
    import pycolmap as _pycolmap

    return _pycolmap
