"""Exceptions raised by solidkit; the CLI turns them into one-line messages."""


class SolidkitError(Exception):
    """Base class: an error a user can act on (bad input, missing metadata, ...)."""


class InputError(SolidkitError):
    """A file is missing, unreadable, corrupt or of the wrong kind."""


class PanoramaError(InputError):
    """An image is not a valid equirectangular panorama (W != 2H, NaN/Inf, wrong channels)."""


class ConventionsError(SolidkitError):
    """A file or checkpoint was written under another conventions version."""
