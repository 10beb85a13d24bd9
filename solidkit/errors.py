"""Exceptions raised by solidkit; the CLI turns them into one-line messages."""


class SolidkitError(Exception):
    """Base class: an error a user can act on (bad input, missing metadata, ...)."""


class InputError(SolidkitError):
    """A file is missing, unreadable, corrupt or of the wrong kind."""


class PanoramaError(InputError):
    """An image is not a valid equirectangular panorama (W != 2H, NaN/Inf, wrong channels)."""


class ConventionsError(SolidkitError):
    """A file or checkpoint was written under another conventions version."""


def validation_message(exc: Exception) -> str:
    """One line ``field.path: message`` for the first error of a pydantic ``ValidationError``."""
    errors = getattr(exc, "errors", None)
    if not callable(errors) or not errors():
        return str(exc).splitlines()[0]
    first = errors()[0]
    return f"{'.'.join(str(p) for p in first['loc'])}: {first['msg']}"
