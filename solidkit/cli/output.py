"""What a command prints: with ``--json`` the result alone, one JSON document on stdout.

Progress, logs and warnings go to stderr, so ``solidkit ... --json | jq`` always reads a whole
document. Every reporter declares the option with :func:`json_option` and prints with :func:`echo_json`.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from typing import Any

import typer
from rich.console import Console

__all__ = ["echo_json", "json_option", "line_console"]


def json_option(what: str = "the summary") -> Any:
    """The ``--json`` option of a command that reports ``what`` (e.g. ``"the build report"``)."""
    return typer.Option(False, "--json", help=f"Print {what} as JSON on stdout (progress and logs on stderr).")


def echo_json(doc: Any, *, indent: int | None = None, default: Callable[[Any], Any] | None = None) -> None:
    """Print ``doc`` as one JSON document on stdout (``indent`` and ``default`` as in :func:`json.dumps`)."""
    typer.echo(json.dumps(doc, indent=indent, default=default))


def line_console(*, stderr: bool = False) -> Console:
    """A rich console for messages printed a line each (problems, errors, warnings): into a pipe or a file a line
    is never broken at the console width (80 columns there), so ``grep`` and logs see whole lines; on a terminal
    it wraps as usual."""
    console = Console(stderr=stderr)
    console.soft_wrap = not console.is_terminal
    return console
