"""One writer at a time per campaign: ``CAMPAIGN_DIR/.lock``.

The steps that write a campaign (``ingest``, ``align``, ``label sun``) and those that read it whole
(``testset build``, ``verify``) run under :func:`campaign_lock`; a second one is refused with a message naming the
running step, its process id and start time, or waits for it (``--wait``).
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Callable, Iterator
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

from solidkit.errors import InputError
from solidkit.fsutil import LockBusy, file_lock

__all__ = ["LOCK_NAME", "campaign_lock", "holder_text"]

LOCK_NAME = ".lock"


def _alive(pid: Any) -> bool:
    if not isinstance(pid, int) or pid <= 0:
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:  # alive, another user's
        return True
    return True


def holder_text(holder: dict[str, Any]) -> str:
    """``align (pid 4242, started 2026-12-02 03:20:05 UTC)`` from a lock file's holder record (a record
    left by a killed process, read before the new holder wrote its own, names no one)."""
    if not holder.get("step") or not _alive(holder.get("pid")):
        return "another step (ingest, align, label sun or testset build)"
    when = f", started {holder['started']}" if holder.get("started") else ""
    return f"{holder['step']} (pid {holder.get('pid', '?')}{when})"


@contextlib.contextmanager
def campaign_lock(
    campaign: str | os.PathLike,
    step: str,
    *,
    wait: bool = False,
    log: Callable[[str], Any] | None = None,
) -> Iterator[None]:
    """Run the block as the campaign's only writer (``step``: what the holder is doing, for others).

    Raises :class:`InputError` when another step holds the campaign, unless ``wait`` (then
    ``log`` hears once what it waits for). The campaign directory is created when missing.
    """
    campaign = Path(campaign)
    started = datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M:%S UTC")
    holder = {"step": step, "pid": os.getpid(), "started": started}

    def waiting(other: dict[str, Any]) -> None:
        if log is not None:
            log(f"{campaign}: waiting for {holder_text(other)} to finish")

    try:
        with file_lock(campaign / LOCK_NAME, holder, wait=wait, on_wait=waiting):
            yield
    except LockBusy as busy:
        raise InputError(
            f"{campaign}: {holder_text(busy.holder)} is running on this campaign; "
            f"run {step} again when it has finished, or add --wait"
        ) from None
