"""``solidkit label ...``: the labeling app and the label store's export."""

from __future__ import annotations

import ipaddress
import json
import secrets
from pathlib import Path

import typer
from rich.console import Console
from rich.table import Table

from solidkit.cli.align import label_sun
from solidkit.errors import InputError
from solidkit.fsutil import atomic_write_text
from solidkit.labeling.store import LabelStore, store_path

app = typer.Typer(no_args_is_help=True)
console = Console(stderr=True)
app.command("sun")(label_sun)  # align/'s automatic sun labels (candidates + reasons) into the store


def _is_loopback(host: str) -> bool:
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host.strip("[]")).is_loopback
    except ValueError:
        return False


def _alignment(campaign: Path) -> dict | None:
    from solidkit.align.schema import ALIGNMENT_FILE, load_alignment

    if not (campaign / ALIGNMENT_FILE).is_file():
        return None
    return load_alignment(campaign).model_dump(mode="json")


def app_url(host: str, port: int) -> str:
    """The address annotators open: a wildcard bind is reached on loopback, an IPv6 host goes in brackets."""
    if host in ("0.0.0.0", "::", "[::]"):
        host = "127.0.0.1"
    bare = host.strip("[]")
    return f"http://[{bare}]:{port}/" if ":" in bare else f"http://{bare}:{port}/"


def read_token(path: Path) -> str:
    """The token on the first line of ``path`` (surrounding white space dropped); a clear error otherwise."""
    try:
        lines = path.read_text(encoding="utf-8").splitlines()
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: cannot read the token file ({exc})") from None
    if not lines or not lines[0].strip():
        raise InputError(f"{path}: the token file is empty")
    return lines[0].strip()


@app.command()
def serve(
    campaign: Path = typer.Argument(..., help="Campaign folder (manifest.json; labels go to CAMPAIGN/labels/)."),
    host: str = typer.Option("127.0.0.1", help="Address to bind. Anything but loopback requires a token."),
    port: int = typer.Option(8765, min=1, max=65535, help="TCP port."),
    token: str | None = typer.Option(
        None,
        envvar="SOLIDKIT_LABEL_TOKEN",
        help=(
            "Access token; prefer $SOLIDKIT_LABEL_TOKEN or --token-file (a --token value is visible to every local "
            "user in the process list). Generated and printed when binding beyond loopback."
        ),
    ),
    token_file: Path | None = typer.Option(
        None, "--token-file", help="Read the access token from the first line of this file (kept out of `ps`)."
    ),
) -> None:
    """Start the browser labeling app: sun centroids, probe pixels, headings, review."""
    # fastapi/uvicorn load here, not at import: `solidkit --help` and every other command stay fast.
    import uvicorn

    from solidkit.labeling.app import LOOPBACK_HOSTS, create_app

    if not campaign.is_dir():
        raise InputError(f"{campaign}: campaign folder not found")
    if not (campaign / "manifest.json").is_file():
        raise InputError(f"{campaign}: no manifest.json (run `solidkit ingest CARD -o {campaign}` first)")
    if token_file is not None:
        if token is not None:
            raise InputError("give the token once: --token (or $SOLIDKIT_LABEL_TOKEN) or --token-file")
        token = read_token(token_file)
    if token is not None and len(token) < 16:
        raise InputError("--token: use at least 16 characters")
    local = _is_loopback(host)
    if not local and token is None:
        token = secrets.token_urlsafe(24)
        typer.echo(f"token (give it to the annotators; it is not shown again): {token}", err=True)
    wildcard = host in ("0.0.0.0", "::", "[::]")
    allowed = ["*"] if wildcard else [host.strip("[]"), host, *LOOPBACK_HOSTS]
    app_ = create_app(campaign, alignment=_alignment(campaign), token=token, allowed_hosts=allowed)
    typer.echo(f"labeling {campaign} at {app_url(host, port)}  (Ctrl+C to stop)", err=True)
    uvicorn.run(app_, host=host.strip("[]"), port=port, log_level="warning", server_header=False)


@app.command()
def export(
    campaign: Path = typer.Argument(..., help="Campaign folder."),
    as_json: bool = typer.Option(False, "--json", help="Print the export (JSON) on stdout."),
    out: Path | None = typer.Option(None, "-o", "--out", help="Write the export (JSON) to this file."),
) -> None:
    """Export the current labels (for the test-set builder); without --json/-o, a summary."""
    if not campaign.is_dir():
        raise InputError(f"{campaign}: campaign folder not found")
    if not store_path(campaign).is_file():
        raise InputError(f"{campaign}: no label store ({store_path(campaign)}); nothing labelled yet")
    doc = LabelStore(campaign, readonly=True).export()
    text = json.dumps(doc, indent=1)
    if out is not None:
        atomic_write_text(out, text + "\n")
        console.print(f"wrote {len(doc['labels'])} labels to {out}")
    if as_json:
        typer.echo(text)
    elif out is None:
        table = Table(title=f"labels in {campaign}")
        for col in ("kind", "auto", "annotator", "reviewed"):
            table.add_column(col)
        for kind, counts in doc["counts"].items():
            table.add_row(kind, *(str(counts.get(s, 0)) for s in ("auto", "annotator", "reviewed")))
        Console().print(table)
