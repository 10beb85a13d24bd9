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
users_app = typer.Typer(no_args_is_help=True, help="The campaign's annotators and reviewers (in its label store).")
app.add_typer(users_app, name="users")
TASK_CHOICES = ("sun", "probe_pixel", "heading")


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


def allowed_hosts(host: str, extra: list[str] | None = None) -> list[str]:
    """Host names the ``Host`` header may carry when serving on ``host``: the loopback names, the
    bound address, and for a wildcard bind this machine's name, full name and addresses (never
    "any": a DNS-rebinding page would pass), plus ``extra`` (names of a reverse proxy)."""
    import socket

    from solidkit.labeling.app import LOOPBACK_HOSTS

    names = [*LOOPBACK_HOSTS, host.strip("[]"), *(extra or [])]
    if host in ("0.0.0.0", "::", "[::]"):
        names += [socket.gethostname(), socket.getfqdn()]
        try:
            names += [str(a[4][0]) for a in socket.getaddrinfo(socket.gethostname(), None)]
        except OSError:
            pass
        for family, probe in ((socket.AF_INET, "192.0.2.1"), (socket.AF_INET6, "2001:db8::1")):
            try:  # the address of the default route (a UDP "connect" sends nothing)
                with socket.socket(family, socket.SOCK_DGRAM) as s:
                    s.connect((probe, 9))
                    names.append(s.getsockname()[0])
            except OSError:
                pass
    out: list[str] = []
    for n in names:
        n = n.split("%")[0]  # an IPv6 zone
        for v in (n, f"[{n}]") if ":" in n and not n.startswith("[") else (n,):
            if v and v not in out:
                out.append(v)
    return out


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
    allow_host: list[str] = typer.Option(
        [], "--allow-host", help="Another name the page may be opened by (a reverse proxy's); repeatable."
    ),
) -> None:
    """Start the browser labeling app: sun centroids, probe pixels, headings, review."""
    # fastapi/uvicorn load here, not at import: `solidkit --help` and every other command stay fast.
    import uvicorn

    from solidkit.labeling.app import create_app

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
    allowed = allowed_hosts(host, allow_host)
    app_ = create_app(campaign, alignment=_alignment(campaign), token=token, allowed_hosts=allowed, warm_cache=True)
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
    doc["agreement"] = _agreement(campaign)
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
        agree = Table(title="agreement (median / p95 apart; n)")
        for col in ("task", "annotator", "vs other annotators", "vs reviewed", "rejected", "skipped"):
            agree.add_column(col)

        def cell(st: dict, unit: str) -> str:
            return "–" if not st["n"] else f"{st['median']:.2f} / {st['p95']:.2f} {unit}; {st['n']}"

        for kind, a in doc["agreement"].items():
            agree.add_row(
                kind, "(all)", cell(a["task"]["vs_others"], a["unit"]), cell(a["task"]["vs_reviewed"], a["unit"])
            )
            for who, st in a["annotators"].items():
                agree.add_row("", who, cell(st["vs_others"], a["unit"]), cell(st["vs_reviewed"], a["unit"]),
                              str(st["rejected"]), str(st["skipped"]))  # fmt: skip
        Console().print(agree)


def _agreement(campaign: Path) -> dict:
    """The agreement summary (``labeling.review.agreement``) over the campaign's items."""
    from solidkit.labeling.review import agreement
    from solidkit.labeling.tasks import TASKS, CampaignIndex

    if not (campaign / "manifest.json").is_file():
        return {}
    return agreement(CampaignIndex(campaign, _alignment(campaign)), LabelStore(campaign, readonly=True), TASKS)


def _store(campaign: Path) -> LabelStore:
    if not campaign.is_dir():
        raise InputError(f"{campaign}: campaign folder not found")
    if not (campaign / "manifest.json").is_file():
        raise InputError(f"{campaign}: no manifest.json (run `solidkit ingest CARD -o {campaign}` first)")
    return LabelStore(campaign)


@users_app.command("add")
def users_add(
    name: str = typer.Argument(..., help="The user's name (what they pick at login; stored with their labels)."),
    campaign: Path = typer.Option(Path("."), "-c", "--campaign", help="Campaign folder."),
    role: str = typer.Option("annotator", "--role", help="annotator (labels) or reviewer (also reviews)."),
) -> None:
    """Add a user (or change their role). Once a campaign has users, only they can log in."""
    store = _store(campaign)
    before = store.users().get(name)
    store.add_user(name, role)
    console.print(f"{name}: {role}" + (f" (was {before})" if before and before != role else ""))


@users_app.command("list")
def users_list(campaign: Path = typer.Option(Path("."), "-c", "--campaign", help="Campaign folder.")) -> None:
    """The campaign's users and their roles (name<TAB>role on stdout)."""
    for name, role in _store(campaign).users().items():
        typer.echo(f"{name}\t{role}")


@app.command()
def assign(
    campaign: Path = typer.Argument(..., help="Campaign folder."),
    to: list[str] = typer.Option(..., "--to", help="An annotator (a registered user); repeat for each."),
    per_item: int = typer.Option(1, "--per-item", min=1, help="Annotators per item (2: double labeling)."),
    task: list[str] = typer.Option(list(TASK_CHOICES), "--task", help="Task(s) to assign (default: all)."),
    blind: bool | None = typer.Option(
        None, "--blind/--no-blind", help="Hide other labels from annotators (default: on when --per-item >= 2)."
    ),
) -> None:
    """Split each task's items between annotators, each item to --per-item of them in turn.

    Replaces the tasks' earlier assignment; labels already saved are kept.
    """
    from solidkit.labeling.tasks import CampaignIndex

    store = _store(campaign)
    names = list(dict.fromkeys(to))
    if per_item > len(names):
        raise InputError(f"--per-item {per_item}: only {len(names)} annotator(s) given with --to")
    bad = [t for t in task if t not in TASK_CHOICES]
    if bad:
        raise InputError(f"--task {bad[0]}: one of {', '.join(TASK_CHOICES)}")
    index = CampaignIndex(campaign, _alignment(campaign))
    table = Table(title=f"assignment ({per_item} per item)")
    for col in ("task", *names):
        table.add_column(col)
    for kind in task:
        keys = list(index.items[kind])
        plan = {key: [names[(i * per_item + j) % len(names)] for j in range(per_item)] for i, key in enumerate(keys)}
        store.assign(kind, plan)
        table.add_row(kind, *(str(sum(n in v for v in plan.values())) for n in names))
    if blind is None:
        blind = per_item >= 2
    store.set_setting("blind", "1" if blind else "0")
    console.print(table)
    console.print(f"blind mode for annotators: {'on' if blind else 'off'}")
