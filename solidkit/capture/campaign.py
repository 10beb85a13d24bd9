"""Campaign ingest: SD cards -> content-addressed originals, a manifest, and derived products.

``solidkit ingest CARD_DIR -o CAMPAIGN_DIR [--jobs N]`` copies every capture on a card once into
``CAMPAIGN_DIR/originals/<sha[:2]>/<sha256>.<ext>`` (read-only, byte-identical, verified),
reads its metadata and the field notes, groups the shots into scenes, Theta positions and
brackets, derives the products (merged HDR per bracket, the low-exposure sun frame per position)
and records everything in ``CAMPAIGN_DIR/manifest.json``. The pieces:

- :mod:`solidkit.capture.manifest`: the manifest schema (versioned pydantic models);
- :mod:`solidkit.capture.card`: what on a card is a capture, field notes or unrelated; the
  per-file worker (hash, validate, copy);
- :mod:`solidkit.capture.fieldnotes`: the field notes format (``docs/field-protocol.md``);
- :mod:`solidkit.capture.grouping`: card layouts, scenes/positions/brackets, notes applied;
- :mod:`solidkit.capture.products`: HDR and sun-frame products and their recipes;
- this module: the run (locking, resuming, parallel workers, the report).

Profiles given with ``--response``, ``--profile`` or ``--vignetting`` are copied into
``CAMPAIGN_DIR/profiles/`` under their content hash and recorded in the manifest; later runs
keep using them until another one is given.

Robustness
----------
Everything is written atomically (temporary file + rename: a killed run never leaves a
half-written file under a final name; stray temporaries are removed by the next run). The
manifest is saved every second during the copy phase; a run killed with ``kill -9`` is resumed
by running the same command again (originals already present are verified by size and not
copied again) and ends with the same manifest as an uninterrupted run: the manifest holds no
timestamps of the run and is a pure function of the cards' files and the grouping parameters.
Per-file problems (empty, truncated or undecodable files, a DNG named ``.jpg``) are collected and
reported at the end while the other files are processed; they are kept in the manifest's
``errors`` (keyed by path, size and mtime) so that an unchanged bad file is not retried. Field
notes are re-read on every run (a refused file is reported again until fixed). A second run
over the same card does nothing and says so. The campaign's lock (:mod:`solidkit.capture.lock`)
refuses a second ingest, an align or a test set build while one runs (or waits: ``wait``).

Environmental errors (disk full, quota, I/O, permissions: :func:`solidkit.fsutil.is_environmental`)
are never remembered: a card file is tried again and a product built again on the next run, and
the message names the final file and the space it needs. ``retry_failed`` retries the products
recorded with an error of their own too. A manifest that cannot be saved is reported
(``IngestReport.manifest_error``); what was written before is kept and found by the next run.

Every run starts with the cheap check of :mod:`solidkit.capture.verify` on the stored captures:
a writable one is made read-only again, a missing or corrupted one whose card file is on the card
being ingested (unchanged) is copied again, and any other is reported (``IngestReport.damaged``;
its products are not rebuilt from it).
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import stat
import time
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path
from typing import Any

from pydantic import BaseModel, Field

from solidkit import __version__
from solidkit.camera.lens import load_profile
from solidkit.capture.card import IMAGE_SUFFIXES, CardScan, folder_layout, ingest_file, ingest_notes, scan_card
from solidkit.capture.frame_merge import load_response
from solidkit.capture.grouping import group_shots
from solidkit.capture.lock import campaign_lock
from solidkit.capture.manifest import (
    MANIFEST_NAME,
    FieldNotesRecord,
    FileError,
    GroupingParams,
    Manifest,
    Product,
    Shot,
    SkippedFile,
    SourceRef,
    load_manifest,
    save_manifest,
)
from solidkit.capture.products import make_product, planned_products, record_profile, tilt_warning
from solidkit.capture.unwarp import load_vignetting
from solidkit.capture.verify import REINGEST, Damage, check_original
from solidkit.envmap.coords import CONVENTIONS_VERSION
from solidkit.errors import InputError
from solidkit.fsutil import SPACE_ERRNOS, sha256_file

__all__ = [
    "IMAGE_SUFFIXES",
    "IngestReport",
    "CardScan",
    "ingest",
    "scan_card",
    "folder_layout",
    "group_shots",
    "summary_rows",
]
"""The manifest's types and loaders live in :mod:`solidkit.capture.manifest`, the products in
:mod:`solidkit.capture.products` (all of them also in the :mod:`solidkit.capture` façade)."""


class IngestReport(BaseModel):
    """What one ingest run did (printed by the CLI; not stored)."""

    files_seen: int = 0
    copied: int = 0
    already_present: int = 0
    unchanged: int = 0
    new_sources: int = 0
    errors: list[FileError] = Field(default_factory=list)
    transient_errors: list[FileError] = Field(
        default_factory=list, description="environmental errors (disk full, permissions, I/O): retried next run"
    )
    known_errors: int = 0
    unrelated: list[str] = Field(default_factory=list)
    skip_reasons: dict[str, str] = Field(default_factory=dict, description="why each unrelated entry was skipped")
    products_built: int = 0
    products_up_to_date: int = 0
    products_removed: int = 0
    product_errors: list[str] = Field(default_factory=list)
    product_errors_transient: int = Field(
        0, description="of product_errors, those of the environment or of a damaged input: built again next run"
    )
    notes_read: int = 0
    notes_errors: list[str] = Field(default_factory=list, description="field notes files refused, one line each")
    regrouped: bool = False
    originals_restored: list[str] = Field(
        default_factory=list, description="stored captures found missing or corrupted and copied again from this card"
    )
    originals_repaired: int = Field(0, description="intact stored captures made read-only again")
    damaged: list[Damage] = Field(
        default_factory=list, description="stored captures missing or corrupted and not on this card (verify)"
    )
    manifest_error: str | None = Field(None, description="why manifest.json could not be saved (disk full, I/O)")

    @property
    def nothing_done(self) -> bool:
        return not (
            self.originals_restored
            or self.originals_repaired
            or self.damaged
            or self.manifest_error
            or self.copied
            or self.new_sources
            or self.errors
            or self.transient_errors
            or self.notes_errors
            or self.products_built
            or self.products_removed
            or self.regrouped
            or self.already_present
        )


def _save(campaign: Path, manifest: Manifest, report: IngestReport) -> None:
    """Save the manifest; a failure of the environment is kept in the report (the next save tries again)."""
    try:
        save_manifest(campaign, manifest)
    except OSError as exc:
        report.manifest_error = f"{exc.filename or campaign / MANIFEST_NAME}: {exc.strerror or exc}"
    else:
        report.manifest_error = None


def _unchanged(path: Path, ref: SourceRef) -> bool:
    try:
        st = path.stat()
    except OSError:
        return False
    return (st.st_size, st.st_mtime_ns) == (ref.size, ref.mtime_ns)


def _check_originals(
    manifest: Manifest, campaign: Path, card: Path, report: IngestReport
) -> tuple[set[str], set[tuple[str, str, int, int]]]:
    """The cheap check of every stored capture (module doc). Returns the sha256 of the damaged ones
    not on this card and the source keys of this card's files to copy again."""
    unusable: set[str] = set()
    again: set[tuple[str, str, int, int]] = set()
    cstr = str(card)
    for shot in manifest.shots:
        problem, hashed = check_original(campaign, shot)
        path = campaign / shot.original
        if problem is None or problem.startswith("writable"):
            with contextlib.suppress(OSError):
                if problem is not None:
                    path.chmod(stat.S_IRUSR | stat.S_IRGRP | stat.S_IROTH)
                    report.originals_repaired += 1
                if hashed and shot.sources:  # intact, under another time (an older campaign): the card file's time
                    os.utime(path, ns=(shot.sources[0].mtime_ns, shot.sources[0].mtime_ns))
            continue
        here = [r for r in shot.sources if r.card == cstr and _unchanged(card / r.path, r)]
        if here:
            with contextlib.suppress(FileNotFoundError):
                if not path.is_symlink():
                    path.chmod(stat.S_IRUSR | stat.S_IWUSR)
                path.unlink()
            report.originals_restored.append(shot.original)
            again.update((r.card, r.path, r.size, r.mtime_ns) for r in here)
            continue
        unusable.add(shot.sha256)
        src = f"{shot.sources[0].card}/{shot.sources[0].path}" if shot.sources else None
        report.damaged.append(
            Damage(
                path=shot.original,
                what="original",
                problem=problem,
                rebuildable=False,
                remedy=f"{REINGEST}{f' ({src})' if src else ''}",
                source=src,
            )
        )
    return unusable, again


def _clean_temporaries(campaign: Path) -> int:
    """Remove temporaries of a killed run (hidden ``.name.xxxx`` files under originals/, products/)."""
    n = 0
    for sub in ("originals", "products"):
        root = campaign / sub
        if not root.is_dir():
            continue
        for dirpath, _, files in os.walk(root):
            for f in files:
                if f.startswith("."):
                    p = Path(dirpath, f)
                    p.chmod(stat.S_IRUSR | stat.S_IWUSR)
                    p.unlink(missing_ok=True)
                    n += 1
    for temp in campaign.glob(f".{MANIFEST_NAME}.*"):
        temp.unlink(missing_ok=True)
    return n


def _die_with_parent(parent: int) -> None:
    """Worker initializer: end this worker when the ingest that started it dies (even by ``kill -9``).

    Linux delivers SIGKILL on the parent's death (``prctl(PR_SET_PDEATHSIG)``); a watchdog thread
    that checks the parent id twice a second covers other systems and a parent that died before
    the ``prctl``.
    """
    import ctypes
    import signal
    import threading

    try:
        ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGKILL)  # 1 = PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        pass

    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(0.5)
        os._exit(1)

    if os.getppid() != parent:
        os._exit(1)
    threading.Thread(target=watch, name="solidkit-parent-watch", daemon=True).start()


def _pool(jobs: int):
    if jobs <= 1:
        return None
    import multiprocessing as mp

    return ProcessPoolExecutor(
        max_workers=jobs, mp_context=mp.get_context("spawn"), initializer=_init_worker, initargs=(os.getpid(),)
    )


def _init_worker(parent: int) -> None:
    """Worker initializer: dies with the ingest (:func:`_die_with_parent`); computes each product on one
    thread, the pool's workers keeping the cores busy (:func:`solidkit.threads.helper_threads`)."""
    from solidkit.threads import set_helper_threads

    set_helper_threads(1)
    _die_with_parent(parent)


def _run_tasks(
    fn: Callable,
    tasks: list[tuple],
    pool: ProcessPoolExecutor | None,
    on_result: Callable[[tuple, dict], None],
    full: Callable[[], bool] = lambda: False,
    on_skip: Callable[[tuple], None] = lambda task: None,
) -> None:
    """Run ``fn(*task)`` for every task, inline (no pool) or in the process pool. Once ``full()`` (the
    disk is full) the tasks not started yet are handed to ``on_skip`` instead: they would fail alike."""
    if pool is None:
        for t in tasks:
            if full():
                on_skip(t)
            else:
                on_result(t, fn(*t))
        return
    futures = {pool.submit(fn, *t): t for t in tasks}
    for fut in as_completed(futures):
        if fut.cancelled():
            on_skip(futures[fut])
            continue
        on_result(futures[fut], fut.result())
        if full():
            for other in futures:
                other.cancel()


def _product_cost(task: tuple) -> int:
    """A product task's relative cost: its input pixels, four times over for a bracket's merge (a bracket of
    the shipped mini card took 3.4 CPU-s, a sun frame 0.5)."""
    product, shots = task[0], task[1]
    pixels = sum(int(s["metadata"].get("width") or 0) * int(s["metadata"].get("height") or 0) for s in shots)
    return pixels * (4 if product["kind"] == "hdr" else 1)


def _space_error(message: str | None) -> bool:
    return bool(message) and any(os.strerror(code) in str(message) for code in SPACE_ERRNOS)


def ingest(
    card_dir: str | os.PathLike,
    campaign_dir: str | os.PathLike,
    *,
    jobs: int = 1,
    grouping: GroupingParams | dict[str, float] | None = None,
    response_path: str | os.PathLike | None = None,
    products: bool = True,
    progress: Any = None,
    lens_profile: str | os.PathLike | None = None,
    vignetting_path: str | os.PathLike | None = None,
    retry_failed: bool = False,
    wait: bool = False,
    log: Callable[[str], Any] | None = None,
) -> IngestReport:
    """Ingest one card into a campaign (see the module docstring). Returns what was done.

    ``response_path``, ``lens_profile`` (a per-unit lens profile JSON, or a shipped profile
    name, overriding the camera model's default) and ``vignetting_path`` (a vignetting profile
    JSON) are validated, recorded in the manifest (files copied into ``profiles/``) and used
    by this and later runs until replaced.

    ``progress(phase, done, total)`` (optional) is called as files and products complete.
    ``retry_failed``: build again the products recorded with an error (environmental errors are
    retried anyway). ``wait``: wait for another step holding the campaign (``log`` says which)
    instead of refusing.
    Raises :class:`InputError` for a missing card, an unreadable manifest or a campaign another
    step holds; per-file problems, damaged originals and a manifest that could not be saved are
    collected in the report (and the manifest) instead.
    """
    card = Path(card_dir).resolve()
    campaign = Path(campaign_dir).resolve()
    if not card.is_dir():
        raise InputError(f"{card_dir}: card directory not found")
    if campaign == card or campaign.is_relative_to(card):
        raise InputError("the campaign directory must not be inside the card")
    if card.is_relative_to(campaign):
        raise InputError("the card must not be inside the campaign directory")
    if campaign.exists() and not campaign.is_dir():
        raise InputError(f"{campaign_dir}: exists and is not a directory")
    # validate everything before the campaign directory is created or touched
    for key, value in (grouping.model_dump() if isinstance(grouping, GroupingParams) else grouping or {}).items():
        if not (math.isfinite(value) and value > 0):
            raise InputError(
                f"--{key.removesuffix('_s').replace('_', '-')} must be a positive number of seconds, got {value}"
            )
    if response_path is not None:
        load_response(Path(response_path))
    if lens_profile is not None:
        lp = load_profile(lens_profile)  # a file, or a shipped name
    if vignetting_path is not None:
        load_vignetting(vignetting_path)
    scan = scan_card(card)
    captures, unrelated = scan.captures, scan.unrelated
    if not captures:
        raise InputError(f"{card_dir}: no captures (.jpg/.jpeg/.dng) on this card")
    throttle = float(os.environ.get("SOLIDKIT_INGEST_THROTTLE_S", "0") or 0)  # testing aid: slow each file down
    report = IngestReport()
    with campaign_lock(campaign, "ingest", wait=wait, log=log), contextlib.ExitStack() as stack:
        pool = _pool(jobs)
        if pool is not None:
            stack.enter_context(pool)
        _clean_temporaries(campaign)
        manifest = load_manifest(campaign)
        before = manifest.model_dump_json()
        manifest.solidkit_version, manifest.conventions_version = __version__, CONVENTIONS_VERSION
        if isinstance(grouping, GroupingParams):
            manifest.grouping = grouping
        elif grouping:  # overrides of the campaign's stored parameters
            manifest.grouping = GroupingParams.model_validate({**manifest.grouping.model_dump(), **grouping})
        if response_path is not None:
            manifest.response = record_profile(campaign, Path(response_path), "response")
        if lens_profile is not None:
            if Path(lens_profile).is_file():
                manifest.lens_profile = {**record_profile(campaign, lens_profile, "lens"), "model": lp.model}
            else:
                manifest.lens_profile = {"kind": "shipped", "name": str(lens_profile), "key": lp.key()}
        if vignetting_path is not None:
            manifest.vignetting = record_profile(campaign, vignetting_path, "vignetting")
        cstr = str(card)
        unusable, again = _check_originals(manifest, campaign, card, report)
        if cstr not in manifest.cards:
            manifest.cards = sorted([*manifest.cards, cstr])

        report.files_seen = len(captures)
        report.unrelated = [p.as_posix() for p in unrelated]
        report.skip_reasons = {p.as_posix(): why for p, why in scan.skipped.items()}
        # forget errors and skips of files that are no longer on this card
        present = {p.as_posix() for p in captures}
        manifest.errors = [e for e in manifest.errors if e.card != cstr or e.path in present]
        still_unrelated = {p.as_posix() for p in unrelated}
        manifest.skipped = [r for r in manifest.skipped if r.card != cstr or r.path in still_unrelated]
        known_skips = {(s.card, s.path, s.reason) for s in manifest.skipped}
        for p in unrelated:
            why = scan.skipped[p]
            if (cstr, p.as_posix(), why) not in known_skips:
                manifest.skipped = [r for r in manifest.skipped if (r.card, r.path) != (cstr, p.as_posix())]
                st = (card / p).lstat()
                manifest.skipped.append(
                    SkippedFile(card=cstr, path=p.as_posix(), size=st.st_size, mtime_ns=st.st_mtime_ns, reason=why)
                )
        manifest.skipped.sort(key=lambda r: (r.card, r.path))

        by_source = {(r.card, r.path, r.size, r.mtime_ns): s for s in manifest.shots for r in s.sources}
        bad = {(e.card, e.path, e.size, e.mtime_ns) for e in manifest.errors}
        todo: list[tuple] = []
        for rel in captures:
            st = (card / rel).stat()
            source_key = (cstr, rel.as_posix(), st.st_size, st.st_mtime_ns)
            if source_key in by_source and source_key not in again:
                report.unchanged += 1
            elif source_key in bad and not retry_failed:
                report.known_errors += 1
            else:
                todo.append((cstr, rel.as_posix(), str(campaign), throttle))

        shots_by_sha = {s.sha256: s for s in manifest.shots}
        last_save = [time.monotonic()]
        done = [0]

        def on_file(task: tuple, res: dict) -> None:
            done[0] += 1
            _, relpath, _, _ = task
            # a file re-ingested (changed, or fixed after an error) replaces its stale records
            manifest.errors[:] = [e for e in manifest.errors if (e.card, e.path) != (cstr, relpath)]
            for s in manifest.shots:
                s.sources = [r for r in s.sources if (r.card, r.path) != (cstr, relpath)]
            if "error" in res:
                fe = FileError.model_validate(res["error"])
                manifest.errors.append(fe)
                report.errors.append(fe)
            elif "transient" in res:  # not remembered: the next run tries the file again
                report.transient_errors.append(FileError.model_validate(res["transient"]))
                disk_full[0] |= _space_error(res["transient"]["message"])
            else:
                shot = Shot.model_validate(res["shot"])
                if shot.sha256 in shots_by_sha:
                    existing = shots_by_sha[shot.sha256]
                    existing.sources = sorted([*existing.sources, *shot.sources], key=lambda r: (r.card, r.path))
                    report.new_sources += 1
                else:
                    manifest.shots.append(shot)
                    shots_by_sha[shot.sha256] = shot
                    if res.get("copied"):
                        report.copied += 1
                    else:
                        report.already_present += 1
            if progress is not None:
                progress("files", done[0], len(todo))
            if time.monotonic() - last_save[0] > 1.0:
                manifest.shots[:] = [s for s in manifest.shots if s.sources]
                _save(campaign, manifest, report)
                last_save[0] = time.monotonic()

        disk_full = [False]

        def not_copied(task: tuple) -> None:
            report.transient_errors.append(
                FileError(card=cstr, path=task[1], size=0, mtime_ns=0, message="not tried: the disk is full")
            )

        if progress is not None:
            progress("files", 0, len(todo))
        _run_tasks(ingest_file, todo, pool, on_file, lambda: disk_full[0], not_copied)
        manifest.shots[:] = [s for s in manifest.shots if s.sources]
        manifest.errors.sort(key=lambda e: (e.card, e.path))
        # field notes: re-read every run (cheap; an edited or fixed file takes effect at once)
        notes = [
            FieldNotesRecord.model_validate(ingest_notes(cstr, rel.as_posix(), str(campaign))) for rel in scan.notes
        ]
        manifest.fieldnotes = sorted(
            [r for r in manifest.fieldnotes if r.card != cstr] + notes, key=lambda r: (r.card, r.path)
        )
        report.notes_read = len(notes)
        report.notes_errors = [r.error for r in notes if r.error]
        for s in manifest.shots:
            s.sources.sort(key=lambda r: (r.card, r.path))
        old_groups = json.dumps([s.model_dump(mode="json") for s in manifest.scenes], sort_keys=True)
        group_shots(manifest)
        report.regrouped = old_groups != json.dumps(
            [s.model_dump(mode="json") for s in manifest.scenes], sort_keys=True
        )
        if manifest.model_dump_json() != before:
            _save(campaign, manifest, report)

        if products:
            _build_products(manifest, campaign, pool, report, progress, unusable, retry_failed)
        manifest.products.sort(key=lambda p: p.id)
        if manifest.model_dump_json() != before or report.manifest_error:
            _save(campaign, manifest, report)
    return report


def _build_products(
    manifest: Manifest,
    campaign: Path,
    pool: ProcessPoolExecutor | None,
    report: IngestReport,
    progress: Any,
    unusable: set[str] | frozenset[str] = frozenset(),
    retry_failed: bool = False,
) -> None:
    wanted = planned_products(manifest)
    existing = {p.id: p for p in manifest.products}
    keep: list[Product] = []
    tasks: list[tuple] = []
    for p in wanted:
        old = existing.get(p.id)
        if (
            old is not None
            and old.recipe_hash == p.recipe_hash
            and (
                (old.error is not None and not old.error_transient and not retry_failed)
                or (
                    old.path
                    and (campaign / old.path).is_file()
                    and (
                        (old.path.startswith("originals/") and not unusable.intersection(old.inputs))
                        or sha256_file(campaign / old.path) == old.sha256
                    )
                )
            )
        ):
            keep.append(old)
            report.products_up_to_date += 1
            if old.error:
                report.product_errors.append(f"{old.id}: {old.error}")
            continue
        lost = [manifest.shot(sha).original for sha in p.inputs if sha in unusable]
        if lost:  # never built from a damaged original
            p.error, p.error_transient = f"not built: its input {lost[0]} is damaged ({REINGEST})", True
            keep.append(p)
            report.product_errors.append(f"{p.id}: {p.error}")
            report.product_errors_transient += 1
            continue
        shots = [manifest.shot(sha).model_dump(mode="json") for sha in p.inputs]
        tasks.append((p.model_dump(mode="json"), shots, str(campaign), manifest.response))
    wanted_ids = {p.id for p in wanted}
    for pid, old in existing.items():
        if pid not in wanted_ids:
            report.products_removed += 1
            if old.path and old.path.startswith("products/"):
                (campaign / old.path).unlink(missing_ok=True)
    results: list[Product] = list(keep)
    done = [0]
    disk_full = [False]

    def on_product(task: tuple, res: dict) -> None:
        prod = Product.model_validate(res)
        results.append(prod)
        report.products_built += 1
        if prod.error:
            report.product_errors.append(f"{prod.id}: {prod.error}")
            report.product_errors_transient += prod.error_transient
            disk_full[0] |= prod.error_transient and _space_error(prod.error)
        done[0] += 1
        if progress is not None:
            progress("products", done[0], len(tasks))
        manifest.products = sorted(results, key=lambda p: p.id)
        _save(campaign, manifest, report)

    def not_built(task: tuple) -> None:
        prod = Product.model_validate(task[0])
        prod.error, prod.error_transient = "not built: the disk is full", True
        on_product(task, prod.model_dump(mode="json"))
        report.products_built -= 1

    if tasks:
        if progress is not None:
            progress("products", 0, len(tasks))
        if pool is not None:  # the longest first: the workers end together instead of one waiting on a late bracket
            tasks.sort(key=_product_cost, reverse=True)
        _run_tasks(make_product, tasks, pool, on_product, lambda: disk_full[0], not_built)
    manifest.products = sorted(results, key=lambda p: p.id)


def summary_rows(manifest: Manifest) -> list[tuple[str, str]]:
    """(label, value) rows describing a campaign, for reports."""
    kinds: dict[str, int] = {}
    for s in manifest.shots:
        kinds[s.kind or "?"] = kinds.get(s.kind or "?", 0) + 1
    n_probes = sum(len(sc.probes) for sc in manifest.scenes)
    n_brackets = sum(len(p.brackets) for sc in manifest.scenes for p in sc.probes)
    positions = [(sc, p) for sc in manifest.scenes for p in sc.probes]
    no_hdr = [f"{sc.id}/{p.id}" for sc, p in positions if not p.brackets]
    no_sun = [f"{sc.id}/{p.id}" for sc, p in positions if p.sun_frame is None]

    def listed(ids: list[str]) -> str:
        return (
            "all have one" if not ids else f"{len(ids)} lack one: {', '.join(ids[:6])}{' ...' if len(ids) > 6 else ''}"
        )

    return [
        ("shots", f"{len(manifest.shots)} ({', '.join(f'{v} {k}' for k, v in sorted(kinds.items()))})"),
        ("scenes / probes / brackets", f"{len(manifest.scenes)} / {n_probes} / {n_brackets}"),
        (
            "camera position marked",
            f"{sum(1 for sc in manifest.scenes if sc.camera_probe)} of {len(manifest.scenes)} scenes",
        ),
        (
            "field notes",
            f"{sum(1 for sc in manifest.scenes if sc.fieldnotes)} of {len(manifest.scenes)} scenes"
            f" ({sum(1 for r in manifest.fieldnotes if r.error)} file(s) refused)",
        ),
        ("positions with an HDR product", listed(no_hdr)),
        ("positions with a sun frame", listed(no_sun)),
        (
            "positions off level (residual tilt)",
            (lambda ids: "none above 0.5°" if not ids else f"{len(ids)} above 0.5°: {', '.join(ids[:6])}")(
                [f"{p.scene}/{p.probe}" for p in manifest.products if tilt_warning(p)]
            ),
        ),
        (
            "HDR response curves",
            (
                lambda kinds: (
                    ", ".join(
                        f"{kinds.count(k)} {label}"
                        for k, label in (
                            ("estimated", "estimated from their bracket"),
                            ("file", "given"),
                            ("srgb_assumed", "sRGB ASSUMED"),
                            ("linear_raw", "raw (linear)"),
                        )
                        if kinds.count(k)
                    )
                    or "-"
                )
            )([p.stats.get("response") for p in manifest.products if p.kind == "hdr"]),
        ),
        ("products", f"{len(manifest.products)} ({sum(1 for p in manifest.products if p.error)} with errors)"),
        (
            "profiles",
            "; ".join(
                f"{name} {_describe(rec, default)}"
                for name, rec, default in (
                    ("response", manifest.response, "estimated per bracket (3+ frames), else sRGB assumed"),
                    ("lens", manifest.lens_profile, "model default"),
                    ("vignetting", manifest.vignetting, "none"),
                )
            ),
        ),
    ]


def _describe(record: dict[str, Any] | None, default: str) -> str:
    if not record or record.get("kind") not in ("file", "shipped"):
        return default
    return record["name"] if record["kind"] == "shipped" else record["path"]
