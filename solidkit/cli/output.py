"""What a command prints: with ``--json`` the result alone, one JSON document on stdout.

Progress, logs and warnings go to stderr, so ``solidkit ... --json | jq`` always reads a whole
document. Every reporter declares the option with :func:`json_option` and prints with :func:`echo_json`.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from typing import Any

import typer

__all__ = ["echo_json", "json_option"]


def json_option(what: str = "the summary") -> Any:
    """The ``--json`` option of a command that reports ``what`` (e.g. ``"the build report"``)."""
    return typer.Option(False, "--json", help=f"Print {what} as JSON on stdout (progress and logs on stderr).")


def echo_json(doc: Any, *, indent: int | None = None, default: Callable[[Any], Any] | None = None) -> None:
    """Print ``doc`` as one JSON document on stdout (``indent`` and ``default`` as in :func:`json.dumps`)."""
    typer.echo(json.dumps(doc, indent=indent, default=default))
