"""The ``solidkit`` command: one sub-command group per pipeline stage."""

from __future__ import annotations

import functools
import importlib
import os
import sys
import traceback
import warnings
from pathlib import Path
from typing import Any, cast

import typer

from solidkit.errors import InputError, InputWarning, SolidkitError
from solidkit.threads import MAX_DEFAULT_THREADS, THREADS_ENV, apply_threads

# Sub-commands are imported only when invoked (``solidkit capture unwarp`` must not pay for torch,
# SciPy or FastAPI at start-up): name -> (module, attribute, help of a group; None for a command).
_GROUPS = {
    "envmap": ("solidkit.cli.envmap", "app", "Inspect, rotate, crop panoramas and find the sun."),
    "capture": ("solidkit.cli.capture", "app", "Theta captures: metadata, dual-fisheye unwarping."),
    "calibrate": (
        "solidkit.cli.calibrate",
        "app",
        "Lens, response-curve, colour, vignetting and photo-camera profiles.",
    ),
    "synth": ("solidkit.cli.synth", "app", "Synthetic SOLID-Img-style data and a virtual campaign (Mitsuba 3)."),
    "testset": ("solidkit.cli.testset", "app", "Build, validate, inspect and export a real test set."),
    "label": (
        "solidkit.cli.label",
        "app",
        "Browser labeling app (sun, probe pixels, headings, review) and label export.",
    ),
}
_COMMANDS = {  # name -> (module, attribute, the one-line help the command list shows without importing it)
    "ingest": (
        "solidkit.cli.ingest",
        "ingest_cli",
        "Copy a card's captures into a checksummed campaign, group scenes/probes/brackets, build products.",
    ),
    "align": (
        "solidkit.cli.align",
        "align_cli",
        "Sun labels, every capture's yaw in the photo's view frame, probe pixels and aligned probes.",
    ),
    "verify": (
        "solidkit.cli.verify",
        "verify_cli",
        "Check a campaign's stored originals, profiles and products against its manifest; exit 1 on damage.",
    ),
    "predict": (
        "solidkit.cli.predict",
        "predict_command",
        "Predict the global HDR sky, its sun direction and a local HDR panorama at each --at pixel.",
    ),
    "train": (
        "solidkit.cli.train",
        "train_command",
        "Train I-Net then P-Net; writes last.pt (resumable state), best_*.pt, model.pt, metrics.csv, tb/.",
    ),
    "eval": (
        "solidkit.cli.eval",
        "eval_command",
        "Sun azimuth/elevation error, global MAE and local SSIM/MAE for the model and baselines; a report.",
    ),
    "finetune": (
        "solidkit.cli.finetune",
        "finetune_command",
        "Fine-tune per fold on the other scenes' LDR probes and sun labels; before/after per fold and pooled.",
    ),
    "demo": (
        "solidkit.cli.demo",
        "demo_command",
        "The whole chain on a small virtual field campaign, into OUT/report.html.",
    ),
}
_HELP = "Real outdoor 360° captures -> a SOLID-Net real test set; evaluate and fine-tune SOLID-Net."


def _root_options(
    threads: int | None = typer.Option(
        None,
        "--threads",
        min=1,
        metavar="N",
        help=f"Threads for torch, OpenCV and the BLAS libraries (default: ${THREADS_ENV}, else half the cores, "
        f"at most {MAX_DEFAULT_THREADS}). Products and alignments are the same bytes whatever N is.",
    ),
) -> None:
    apply_threads(threads)


def build_app(only: str | None = None, *, listing: bool = False) -> typer.Typer:
    """The ``solidkit`` typer app with every sub-command, or with only the one named ``only`` (what
    :func:`main` runs: the other sub-commands' modules are not imported). ``listing``: every command
    by name and one-line help only, importing none of them (``solidkit --help`` in a fraction of the time)."""
    root = typer.Typer(
        name="solidkit", help=_HELP, no_args_is_help=True, pretty_exceptions_enable=False, add_completion=False
    )
    root.callback()(_root_options)  # a group even when one sub-command is registered
    if listing:  # in the order typer lists them: commands, then groups
        for name, (_, _, help_text) in (*_COMMANDS.items(), *_GROUPS.items()):
            root.command(name, help=help_text, add_help_option=False)(_listed)
    for name, (module, attr, help_text) in _GROUPS.items():
        if not listing and only in (None, name):
            root.add_typer(getattr(importlib.import_module(module), attr), name=name, help=help_text)
    for name, (module, attr, _) in _COMMANDS.items():
        if not listing and only in (None, name):
            root.command(name)(getattr(importlib.import_module(module), attr))
    _guard(root)
    return root


def _listed() -> None:  # pragma: no cover - a listed command is never run: main() builds the real one
    raise RuntimeError("a listed command runs only once built for real")


def __getattr__(name: str):
    if name == "app":  # ``from solidkit.cli import app`` (tests, CliRunner): every sub-command
        globals()["app"] = build_app()
        return globals()["app"]
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


_OUTPUTS = ("out", "ghost_mask")  # the parameters naming what a command writes
_IN_PLACE = ("add_to",)  # inputs a command updates on purpose (calibrate lens --add-to)


def _is_file(value: object) -> bool:
    try:
        return isinstance(value, (str, Path)) and bool(str(value)) and Path(value).is_file()
    except OSError:  # e.g. a name too long to be a path
        return False


def refuse_overwriting_inputs(callback):
    """Wrap a command callback: an output that names one of the command's input files is refused
    (:class:`InputError`) before any work, so originals are never overwritten."""

    @functools.wraps(callback)
    def guarded(**kwargs):
        inputs = {
            Path(v).resolve()
            for name, value in kwargs.items()
            if name not in _OUTPUTS and name not in _IN_PLACE
            for v in (value if isinstance(value, (list, tuple)) else [value])
            if _is_file(v)
        }
        for name in _OUTPUTS:
            out = kwargs.get(name)
            if _is_file(out) and Path(out).resolve() in inputs:
                raise InputError(f"{out}: is an input of this command; refusing to overwrite it")
        return callback(**kwargs)

    return guarded


def _guard(typer_app: typer.Typer) -> None:
    for info in typer_app.registered_commands:
        if not getattr(info.callback, "_refuses_overwriting", False):  # sub-apps are shared by every build_app
            guarded = refuse_overwriting_inputs(info.callback)
            guarded._refuses_overwriting = True
            info.callback = guarded
    for group in typer_app.registered_groups:
        assert group.typer_instance is not None  # add_typer always gives one
        _guard(group.typer_instance)


DEBUG_ENV = "SOLIDKIT_DEBUG"  # SOLIDKIT_DEBUG=1: the traceback behind the one-line error, on stderr


def _fail(message: str, code: int) -> None:
    if os.environ.get(DEBUG_ENV, "") not in ("", "0"):
        traceback.print_exc(file=sys.stderr)  # called inside the except block: the exception being handled
    typer.secho(f"error: {message}", err=True, fg="red")
    sys.exit(code)


def _one_line(text: str) -> str:
    return " ".join(line.strip() for line in str(text).splitlines() if line.strip())


def _show_warning(message, category, filename, lineno, file=None, line=None, _default=warnings.showwarning) -> None:
    """An :class:`InputWarning` as one ``warning:`` line on stderr; other warnings as Python shows them."""
    if issubclass(category, InputWarning):
        typer.secho(f"warning: {_one_line(str(message))}", err=True, fg="yellow")
    else:
        _default(message, category, filename, lineno, file, line)


def main() -> None:
    """Entry point: user errors become one line on stderr and exit code 2 (unforeseen ones exit 1), never a
    traceback unless ``SOLIDKIT_DEBUG=1`` asks for it; input warnings are one ``warning:`` line each."""
    warnings.showwarning = _show_warning
    args = sys.argv[1:]
    first = next(
        (a for i, a in enumerate(args) if not a.startswith("-") and (i == 0 or args[i - 1] != "--threads")), None
    )
    try:
        known = first in _GROUPS or first in _COMMANDS
        listing = first is None and (not args or args[-1] in ("--help", "-h"))  # the command list alone
        code = build_app(first if known else None, listing=listing)(
            standalone_mode=False
        )  # a typer.Exit(n) raised in a command comes back as n here
    except SolidkitError as exc:
        _fail(str(exc), 2)
    except (typer.Abort, KeyboardInterrupt):
        typer.secho("aborted", err=True)
        sys.exit(130)
    except typer.Exit as exc:
        sys.exit(exc.exit_code)
    except typer.TyperException as exc:  # typer's own errors (a usage error carries its context)
        ctx = getattr(exc, "ctx", None)
        message = exc.format_message()
        if ctx is not None and (not message.strip() or "\n" in message.strip()):  # a bare group: its help
            cast(Any, exc).show()  # (rich has printed the help already; plain typer's is the message)
            sys.exit(exc.exit_code)
        hint = f" (see '{ctx.command_path} --help')" if ctx is not None else ""  # bad option or argument
        _fail(f"{message}{hint}", exc.exit_code)
    except OSError as exc:  # the file system said no: a file where a folder must be, permissions, disk full
        where = f"{exc.filename}: " if exc.filename else ""
        reason = exc.strerror or str(exc)
        if isinstance(exc, FileExistsError):
            reason += " (a file is where a folder is needed)"
        _fail(f"{where}{reason}", 2)
    except Exception as exc:  # anything unforeseen: still one line
        hint = "" if os.environ.get(DEBUG_ENV, "") not in ("", "0") else f" (run with {DEBUG_ENV}=1 for the traceback)"
        name = type(exc).__name__
        if name.islower():  # e.g. cv2.error, whose text starts "OpenCV(...) ... error: ...": "error: error: ..."
            name = f"{type(exc).__module__.split('.')[0]}.{name}"
        _fail(f"{name}: {_one_line(str(exc))}{hint}", 1)
    if isinstance(code, int) and not isinstance(code, bool) and code != 0:
        sys.exit(code)


if __name__ == "__main__":
    main()
