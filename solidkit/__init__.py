"""solidkit: a real-data toolkit for SOLID-Net (spatially-varying outdoor lighting estimation)."""

from solidkit import _imports  # noqa: F401  (cv2 before pycolmap; see _imports)
from solidkit.envmap.coords import CONVENTIONS_VERSION

__version__ = "0.1.0"
__all__ = ["CONVENTIONS_VERSION", "__version__"]
