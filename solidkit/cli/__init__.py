"""The ``solidkit`` command: one sub-command group per pipeline stage."""

from __future__ import annotations

import functools
import os
import sys
import traceback
from pathlib import Path

import typer
from typer._click.exceptions import ClickException, NoArgsIsHelpError, UsageError  # typer >= 0.16 vendors click

from solidkit.cli.align import align_cli
from solidkit.cli.calibrate import app as calibrate_app
from solidkit.cli.ingest import ingest_cli
from solidkit.cli.label import app as label_app
from solidkit.cli.capture import app as capture_app
from solidkit.cli.envmap import app as envmap_app
from solidkit.cli.demo import demo_command
from solidkit.cli.eval import eval_command
from solidkit.cli.finetune import finetune_command
from solidkit.errors import InputError, SolidkitError
from solidkit.cli.predict import predict_command
from solidkit.cli.synth import app as synth_app
from solidkit.cli.train import train_command
from solidkit.cli.testset import app as testset_app

app = typer.Typer(
    name="solidkit",
    help="Real outdoor 360° captures -> a SOLID-Net real test set; evaluate and fine-tune SOLID-Net.",
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    add_completion=False,
)
app.add_typer(envmap_app, name="envmap", help="Inspect, rotate, crop panoramas and find the sun.")
app.add_typer(capture_app, name="capture", help="Theta captures: metadata, dual-fisheye unwarping.")
app.add_typer(calibrate_app, name="calibrate", help="Lens, response-curve, colour, vignetting and photo-camera profiles.")
app.add_typer(synth_app, name="synth", help="Synthetic SOLID-Img-style data and a virtual campaign (Mitsuba 3).")
app.add_typer(testset_app, name="testset", help="Build, validate, inspect and export a real test set.")
app.add_typer(label_app, name="label", help="Browser labeling app (sun, probe pixels, headings, review) and label export.")
app.command("ingest")(ingest_cli)
app.command("align")(align_cli)
app.command("predict")(predict_command)
app.command("train")(train_command)
app.command("eval")(eval_command)
app.command("finetune")(finetune_command)
app.command("demo")(demo_command)


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
        info.callback = refuse_overwriting_inputs(info.callback)
    for group in typer_app.registered_groups:
        _guard(group.typer_instance)


_guard(app)


DEBUG_ENV = "SOLIDKIT_DEBUG"  # SOLIDKIT_DEBUG=1: the traceback behind the one-line error, on stderr


def _fail(message: str, code: int) -> None:
    if os.environ.get(DEBUG_ENV, "") not in ("", "0"):
        traceback.print_exc(file=sys.stderr)  # called inside the except block: the exception being handled
    typer.secho(f"error: {message}", err=True, fg="red")
    sys.exit(code)


def main() -> None:
    """Entry point: user errors become one line on stderr and exit code 2 (unforeseen ones exit 1), never a
    traceback unless ``SOLIDKIT_DEBUG=1`` asks for it."""
    try:
        code = app(standalone_mode=False)  # a typer.Exit(n) raised in a command comes back as n here
    except SolidkitError as exc:
        _fail(str(exc), 2)
    except (typer.Abort, KeyboardInterrupt):
        typer.secho("aborted", err=True)
        sys.exit(130)
    except typer.Exit as exc:
        sys.exit(exc.exit_code)
    except NoArgsIsHelpError as exc:  # a bare group: its help
        exc.show()
        sys.exit(exc.exit_code)
    except UsageError as exc:  # bad option or argument: one line, naming where help is
        hint = f" (see '{exc.ctx.command_path} --help')" if exc.ctx is not None else ""
        _fail(f"{exc.format_message()}{hint}", exc.exit_code)
    except ClickException as exc:
        _fail(exc.format_message(), exc.exit_code)
    except OSError as exc:  # the file system said no: a file where a folder must be, permissions, disk full
        where = f"{exc.filename}: " if exc.filename else ""
        reason = exc.strerror or str(exc)
        if isinstance(exc, FileExistsError):
            reason += " (a file is where a folder is needed)"
        _fail(f"{where}{reason}", 2)
    except Exception as exc:  # anything unforeseen: still one line
        hint = "" if os.environ.get(DEBUG_ENV, "") not in ("", "0") else f" (run with {DEBUG_ENV}=1 for the traceback)"
        _fail(f"{type(exc).__name__}: {exc}{hint}", 1)
    if isinstance(code, int) and not isinstance(code, bool) and code != 0:
        sys.exit(code)


if __name__ == "__main__":
    main()
