"""The panorama core shared by every part of solidkit (conventions: docs/conventions.md)."""

from solidkit.envmap.coords import *  # noqa: F401,F403
from solidkit.envmap.io import *  # noqa: F401,F403
from solidkit.envmap.resample import *  # noqa: F401,F403
from solidkit.envmap.perspective import *  # noqa: F401,F403
from solidkit.envmap.cubemap import *  # noqa: F401,F403
from solidkit.envmap.sh import *  # noqa: F401,F403
from solidkit.envmap.sun import *  # noqa: F401,F403
