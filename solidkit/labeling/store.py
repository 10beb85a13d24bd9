"""The campaign's label store: human and automatic labels with full history, undo and
optimistic concurrency, in one SQLite database (WAL) at ``CAMPAIGN/labels/labels.sqlite``.

Every change is an *event* (append-only table ``events``) carrying who made it, when, its
source (``auto`` / ``annotator`` / ``reviewed``) and the value it set; table ``labels`` points
at the event holding each label's current state and carries its version. A change is one
``BEGIN IMMEDIATE`` transaction (event insert + pointer update), so a process killed at any
instant (``kill -9``) leaves either the old or the new state, never a mix (SQLite's WAL
journal; ``synchronous=FULL`` also makes committed changes survive a power cut).

Rules
-----
- **Versions.** A label's version counts the changes applied to it (0 = never labelled).
  ``put(..., expected_version=v)`` succeeds only if the current version is ``v``; otherwise it
  raises :class:`LabelConflict` carrying the current label and writes nothing, so the caller
  (the second of two annotators) still holds its own value and can retry on top of the winner.
- **Auto never overwrites a human.** A ``source="auto"`` put onto a label whose current source
  is ``annotator`` or ``reviewed`` is kept in the history (``applied = False``) and the human
  label is returned unchanged.
- **Idempotent.** A put identical to the current state (value, source, annotator, flags) is
  a no-op returning the current label (re-running align adds no history).
- **Undo** restores the state before the last applied change (repeatable: it walks back
  through the changes), itself recorded as a change with its own version.
- **Team** (schema 2): ``users`` (name, role ``annotator`` or ``reviewer``), ``assignments``
  (which annotators label which item), ``verdicts`` (a reviewer's accept or reject of one
  annotator's value, with a comment) and ``notes`` (an annotator's note on an item, or "skip:
  can't tell" with the reason). Once users exist, only a reviewer may write ``reviewed``. A
  schema-1 store is migrated (tables added) the first time it is opened for writing; read-only it
  reads as having none of these.

Label values (``docs/conventions.md`` for frames and angles; degrees at this edge):

===============  =====================  =====================================================
kind             key                    value
===============  =====================  =====================================================
``sun``          ``"<scene>/<probe>"``  ``{found, azimuth_deg, elevation_deg, uncertainty_deg}``
                                        in that capture's sun_frame panorama (its level frame);
                                        optional ``candidates``
``sun_scene``    ``"<scene>"``          same fields, in the photo's panorama frame
``probe_pixel``  ``"<scene>/<probe>"``  ``{x, y}``: full-resolution photo pixels (§1 centres)
``heading``      ``"<scene>/<probe>"``  ``{yaw_deg}``: capture level frame -> photo panorama
===============  =====================  =====================================================
"""

from __future__ import annotations

import builtins
import json
import math
import os
import re
import sqlite3
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, Literal, cast

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from solidkit.envmap.coords import CONVENTIONS_VERSION, wrap_angle
from solidkit.errors import InputError, SolidkitError, validation_message

__all__ = [
    "STORE_SCHEMA_VERSION",
    "KINDS",
    "HUMAN_SOURCES",
    "Source",
    "Label",
    "Change",
    "LabelConflict",
    "LabelStore",
    "SunValue",
    "ProbePixelValue",
    "HeadingValue",
    "store_path",
    "validate_value",
    "opinions",
    "check_name",
    "ROLES",
    "Verdict",
    "Note",
]

STORE_SCHEMA_VERSION = 2
READABLE_SCHEMAS = (1, 2)
ROLES = ("annotator", "reviewer")
Source = Literal["auto", "annotator", "reviewed"]
HUMAN_SOURCES = frozenset({"annotator", "reviewed"})
MAX_VALUE_BYTES = 64 * 1024  # one label's JSON; candidates lists stay far below this
_ID = r"[A-Za-z0-9][A-Za-z0-9_.\-]*"
_NAME = re.compile(r"^[^\x00-\x1f\x7f]{1,64}$")  # annotator names: printable, short

# Fault injection for the crash tests: called inside the write transaction, after the event
# row is inserted and before the label row is updated and the transaction committed.
_mid_write_hook: Callable[[], None] | None = None


class _Value(BaseModel):
    model_config = ConfigDict(extra="allow")  # producers may add fields (method, confidence, ...)


class SunValue(_Value):
    """A sun direction (degrees, conventions §3/§6); ``found = False`` carries no angles."""

    found: bool
    azimuth_deg: float | None = Field(None, ge=-180.0, le=180.0)
    elevation_deg: float | None = Field(None, ge=-90.0, le=90.0)
    uncertainty_deg: float | None = Field(None, ge=0.0, le=180.0)
    candidates: list[dict[str, Any]] | None = None

    @model_validator(mode="after")
    def _angles(self) -> SunValue:
        if self.found and (self.azimuth_deg is None or self.elevation_deg is None):
            raise ValueError("found = true needs azimuth_deg and elevation_deg")
        if not self.found:
            self.azimuth_deg = self.elevation_deg = None
        elif self.azimuth_deg == 180.0:
            self.azimuth_deg = -180.0  # azimuth lives in [-180, 180)
        return self


class ProbePixelValue(_Value):
    """A probe's pixel in the full-resolution photo (OpenCV pixel centres, conventions §1)."""

    x: float = Field(ge=-0.5)
    y: float = Field(ge=-0.5)


class HeadingValue(_Value):
    """Yaw (degrees) of a capture's level frame in the photo's panorama frame."""

    yaw_deg: float = Field(allow_inf_nan=False, description="wrapped to [-180, 180)")

    @field_validator("yaw_deg")
    @classmethod
    def _wrap(cls, v: float) -> float:
        return wrap_angle(v, 360.0)


_KEYS = {
    "sun": re.compile(rf"^{_ID}/{_ID}$"),
    "sun_scene": re.compile(rf"^{_ID}$"),
    "probe_pixel": re.compile(rf"^{_ID}/{_ID}$"),
    "heading": re.compile(rf"^{_ID}/{_ID}$"),
}
_VALUES: dict[str, type[_Value]] = {
    "sun": SunValue,
    "sun_scene": SunValue,
    "probe_pixel": ProbePixelValue,
    "heading": HeadingValue,
}
KINDS = tuple(_KEYS)


def _finite(obj: Any) -> bool:
    if isinstance(obj, float):
        return math.isfinite(obj)
    if isinstance(obj, dict):
        return all(_finite(v) for v in obj.values())
    if isinstance(obj, (list, tuple)):
        return all(_finite(v) for v in obj)
    return True


def validate_value(kind: str, key: str, value: dict[str, Any]) -> dict[str, Any]:
    """Check ``kind``, ``key`` and ``value`` against the table above; return the normalised value.

    Raises
    ------
    InputError
        Unknown kind, malformed key, invalid or non-finite value, or a value over 64 KiB.
    """
    if kind not in _KEYS:
        raise InputError(f"label kind {kind!r}: not one of {', '.join(KINDS)}")
    if not isinstance(key, str) or not _KEYS[kind].match(key):
        form = "<scene>" if kind == "sun_scene" else "<scene>/<probe>"
        raise InputError(f"label key {key!r}: a {kind} key is {form!r} (letters, digits, _ . -)")
    if not isinstance(value, dict):
        raise InputError(f"{kind} {key}: value must be a JSON object")
    try:
        norm = _VALUES[kind].model_validate(value).model_dump(exclude_none=False)
    except ValidationError as exc:
        raise InputError(f"{kind} {key}: {validation_message(exc)}") from None
    if norm.get("candidates", 0) is None:
        del norm["candidates"]
    if not _finite(norm):
        raise InputError(f"{kind} {key}: value has a NaN or infinite number")
    if len(json.dumps(norm)) > MAX_VALUE_BYTES:
        raise InputError(f"{kind} {key}: value larger than {MAX_VALUE_BYTES} bytes")
    return norm


class Label(BaseModel):
    """A label's current state (contract C2)."""

    kind: str
    key: str
    value: dict[str, Any]
    source: Source
    annotator: str
    version: int = Field(description="number of changes applied to this label so far")
    time: datetime = Field(description="UTC time of the change that set this state")
    flags: list[str] = Field(default_factory=list)


class Change(BaseModel):
    """One entry of a label's history.

    ``op`` is ``put`` (a new value), ``undo`` (restored the state before the last change) or
    ``kept`` (an automatic proposal not applied because a human label was current).
    ``actor`` made the change; ``annotator``/``source`` describe the value it set (after an
    undo, the restored value's author). ``value`` is None when the change removed the label.
    """

    id: int
    kind: str
    key: str
    op: Literal["put", "undo", "kept"]
    applied: bool
    version: int = Field(description="label version after this change (unchanged when not applied)")
    actor: str
    time: datetime
    value: dict[str, Any] | None
    source: Source | None
    annotator: str | None
    flags: list[str] = Field(default_factory=list)


class LabelConflict(SolidkitError):
    """A put or undo was based on an out-of-date version; nothing was written.

    Attributes
    ----------
    current : Label | None
        The label as it is now (None if absent).
    current_version : int
        Its version (0 if never labelled).
    expected_version : int
        The version the caller based its change on.
    """

    def __init__(self, kind: str, key: str, expected: int, current: Label | None, current_version: int):
        who = f" by {current.annotator} ({current.source})" if current else ""
        super().__init__(
            f"{kind} {key}: changed to version {current_version}{who} since version {expected}; "
            "reload it and apply your change again"
        )
        self.kind, self.key = kind, key
        self.expected_version = expected
        self.current = current
        self.current_version = current_version


class Verdict(BaseModel):
    """A reviewer's decision on one annotator's value (``event``: the id of that value's change)."""

    id: int
    kind: str
    key: str
    event: int
    annotator: str
    verdict: Literal["accept", "reject"]
    comment: str
    reviewer: str
    time: datetime


class Note(BaseModel):
    """An annotator's latest note on an item; ``skip``: "can't tell", the note is the reason."""

    kind: str
    key: str
    annotator: str
    skip: bool
    text: str
    time: datetime


def opinions(history: list[Change], *, since_review: bool = True) -> dict[str, Change]:
    """Each human annotator's latest applied value in a label's ``history`` since the last
    ``reviewed`` change (a review settles what came before; ``since_review=False``: over the
    whole history, reviewers' own values included); values later undone by their own author are
    left out. ``{annotator: Change}``."""
    latest: dict[str, Change] = {}
    for ch in history:
        if not ch.applied:
            continue
        if ch.op == "put" and ch.source == "reviewed" and since_review:
            latest = {}
        elif ch.op == "put" and ch.source in HUMAN_SOURCES and ch.annotator:
            latest[ch.annotator] = ch
        elif ch.op == "undo" and ch.actor in latest and latest[ch.actor].version == ch.version - 1:
            del latest[ch.actor]
    return latest


def store_path(campaign_dir: str | os.PathLike) -> Path:
    """Path of a campaign's label database."""
    return Path(campaign_dir) / "labels" / "labels.sqlite"


_SCHEMA = """
CREATE TABLE IF NOT EXISTS meta (name TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS events (
    id        INTEGER PRIMARY KEY AUTOINCREMENT,
    kind      TEXT NOT NULL,
    key       TEXT NOT NULL,
    op        TEXT NOT NULL CHECK (op IN ('put', 'undo', 'kept')),
    applied   INTEGER NOT NULL,
    version   INTEGER NOT NULL,
    actor     TEXT NOT NULL,
    time      TEXT NOT NULL,
    value     TEXT,
    source    TEXT,
    annotator TEXT,
    flags     TEXT NOT NULL DEFAULT '[]',
    parent    INTEGER REFERENCES events(id)
);
CREATE INDEX IF NOT EXISTS events_label ON events (kind, key, id);
CREATE TABLE IF NOT EXISTS labels (
    kind    TEXT NOT NULL,
    key     TEXT NOT NULL,
    version INTEGER NOT NULL,
    event   INTEGER NOT NULL REFERENCES events(id),
    PRIMARY KEY (kind, key)
);
"""
_SCHEMA_2 = """
CREATE TABLE IF NOT EXISTS users (
    name    TEXT PRIMARY KEY,
    role    TEXT NOT NULL CHECK (role IN ('annotator', 'reviewer')),
    created TEXT NOT NULL
);
CREATE TABLE IF NOT EXISTS assignments (
    kind      TEXT NOT NULL,
    key       TEXT NOT NULL,
    annotator TEXT NOT NULL,
    PRIMARY KEY (kind, key, annotator)
);
CREATE TABLE IF NOT EXISTS verdicts (
    id        INTEGER PRIMARY KEY AUTOINCREMENT,
    kind      TEXT NOT NULL,
    key       TEXT NOT NULL,
    event     INTEGER NOT NULL REFERENCES events(id),
    annotator TEXT NOT NULL,
    verdict   TEXT NOT NULL CHECK (verdict IN ('accept', 'reject')),
    comment   TEXT NOT NULL,
    reviewer  TEXT NOT NULL,
    time      TEXT NOT NULL
);
CREATE TABLE IF NOT EXISTS notes (
    id        INTEGER PRIMARY KEY AUTOINCREMENT,
    kind      TEXT NOT NULL,
    key       TEXT NOT NULL,
    annotator TEXT NOT NULL,
    skip      INTEGER NOT NULL,
    text      TEXT NOT NULL,
    time      TEXT NOT NULL
);
"""
MAX_COMMENT = 500  # characters of a verdict's comment or a note
# ``parent``: for an applied event, the event whose state it replaced in the undo sense (NULL:
# the label was absent before); undo restores parent's state and inherits parent's parent.


def _now() -> str:
    return datetime.now(timezone.utc).isoformat(timespec="microseconds")


def _finite_text(text: str) -> bool:
    return all(c in "\n\t" or c.isprintable() for c in text)


def check_name(name: str, what: str = "annotator") -> str:
    if not isinstance(name, str) or not _NAME.match(name) or name != name.strip():
        raise InputError(f"{what} {name!r}: 1-64 printable characters, no surrounding spaces")
    return name


class LabelStore:
    """A campaign's label database (contract C2).

    Parameters
    ----------
    campaign_dir : path
        The campaign folder; the database is ``campaign_dir/labels/labels.sqlite`` (created on
        first use, with its folder).
    readonly : bool
        Open without creating or writing anything (``export`` of a finished campaign).

    Notes
    -----
    Safe to share between threads and processes: each call opens its own connection; writers
    serialise on SQLite's write lock (``busy_timeout`` 10 s).
    """

    def __init__(self, campaign_dir: str | os.PathLike, *, readonly: bool = False):
        self.campaign_dir = Path(campaign_dir)
        self.path = store_path(campaign_dir)
        self.readonly = readonly
        if not self.campaign_dir.is_dir():
            raise InputError(f"{self.campaign_dir}: not a campaign folder")
        if readonly:
            if not self.path.is_file():
                raise InputError(f"{self.path}: no label store in this campaign")
        else:
            self.path.parent.mkdir(exist_ok=True)
        with self._connect() as con:
            if not readonly:
                with self._write(con):
                    old = con.execute("SELECT name FROM sqlite_master WHERE name = 'meta'").fetchone() and dict(
                        con.execute("SELECT name, value FROM meta").fetchall()
                    )
                    if old and int(old.get("schema_version", 1)) not in READABLE_SCHEMAS:
                        raise InputError(
                            f"{self.path}: label store schema {old['schema_version']}, this solidkit reads "
                            f"{', '.join(map(str, READABLE_SCHEMAS))}"
                        )
                    for stmt in (_SCHEMA + _SCHEMA_2).split(";"):
                        if stmt.strip():
                            con.execute(stmt)
                    con.execute(
                        "INSERT OR IGNORE INTO meta VALUES ('schema_version', ?), ('conventions_version', ?)",
                        (str(STORE_SCHEMA_VERSION), str(CONVENTIONS_VERSION)),
                    )
                    con.execute(  # schema 1 -> 2: the team tables above were added
                        "UPDATE meta SET value = ? WHERE name = 'schema_version'", (str(STORE_SCHEMA_VERSION),)
                    )
            meta = dict(con.execute("SELECT name, value FROM meta").fetchall())
            self._team = con.execute("SELECT name FROM sqlite_master WHERE name = 'users'").fetchone() is not None
        self.schema_version = int(meta.get("schema_version", STORE_SCHEMA_VERSION))
        if self.schema_version not in READABLE_SCHEMAS:
            raise InputError(
                f"{self.path}: label store schema {meta['schema_version']}, this solidkit reads "
                f"{', '.join(map(str, READABLE_SCHEMAS))}"
            )
        if int(meta.get("conventions_version", CONVENTIONS_VERSION)) != CONVENTIONS_VERSION:
            raise InputError(f"{self.path}: labels written under conventions version {meta['conventions_version']}")

    # -- connections -------------------------------------------------------------------------
    @contextmanager
    def _connect(self) -> Iterator[sqlite3.Connection]:
        try:
            if self.readonly:
                con = sqlite3.connect(
                    f"{self.path.resolve().as_uri()}?mode=ro", uri=True, timeout=10.0, isolation_level=None
                )
            else:
                con = sqlite3.connect(self.path, timeout=10.0, isolation_level=None)
        except sqlite3.Error as exc:
            raise InputError(f"{self.path}: cannot open the label store ({exc})") from None
        try:
            con.execute("PRAGMA busy_timeout = 10000")
            if not self.readonly:
                mode = con.execute("PRAGMA journal_mode = WAL").fetchone()[0]
                if mode.lower() != "wal":
                    raise InputError(f"{self.path}: cannot use WAL journaling (file system without shared memory?)")
                con.execute("PRAGMA synchronous = FULL")
            con.execute("PRAGMA foreign_keys = ON")
            yield con
        except sqlite3.DatabaseError as exc:
            raise InputError(f"{self.path}: {exc}") from None
        finally:
            con.close()

    @contextmanager
    def _write(self, con: sqlite3.Connection) -> Iterator[None]:
        if self.readonly:
            raise InputError(f"{self.path}: opened read-only")
        con.execute("BEGIN IMMEDIATE")
        try:
            yield
        except BaseException:
            con.execute("ROLLBACK")
            raise
        con.execute("COMMIT")

    # -- reading -----------------------------------------------------------------------------
    _LABEL_SQL = (
        "SELECT l.kind, l.key, l.version, e.value, e.source, e.annotator, e.time, e.flags, e.id, e.parent "
        "FROM labels l JOIN events e ON e.id = l.event"
    )

    @staticmethod
    def _label(row: tuple) -> Label | None:
        kind, key, version, value, source, annotator, time, flags = row[:8]
        if value is None:  # removed by undo
            return None
        return Label(
            kind=kind, key=key, value=json.loads(value), source=source, annotator=annotator,
            version=version, time=datetime.fromisoformat(time), flags=json.loads(flags),
        )  # fmt: skip

    def _current(self, con: sqlite3.Connection, kind: str, key: str) -> tuple | None:
        return con.execute(self._LABEL_SQL + " WHERE l.kind = ? AND l.key = ?", (kind, key)).fetchone()

    def get(self, kind: str, key: str) -> Label | None:
        """The current label, or None (never labelled, or removed by undo)."""
        with self._connect() as con:
            row = self._current(con, kind, key)
        return self._label(row) if row else None

    def version(self, kind: str, key: str) -> int:
        """Current version (0 if never labelled); the ``expected_version`` for the next put."""
        with self._connect() as con:
            row = con.execute("SELECT version FROM labels WHERE kind = ? AND key = ?", (kind, key)).fetchone()
        return row[0] if row else 0

    def list(self, kind: str | None = None) -> list[Label]:
        """All current labels (of one kind), ordered by kind and key."""
        where, args = (" WHERE l.kind = ?", (kind,)) if kind else ("", ())
        with self._connect() as con:
            rows = con.execute(self._LABEL_SQL + where + " ORDER BY l.kind, l.key", args).fetchall()
        return [lab for lab in map(self._label, rows) if lab is not None]

    _CHANGE_SQL = "SELECT id, kind, key, op, applied, version, actor, time, value, source, annotator, flags FROM events"

    @staticmethod
    def _change(r: tuple) -> Change:
        return Change(
            id=r[0], kind=r[1], key=r[2], op=r[3], applied=bool(r[4]), version=r[5], actor=r[6],
            time=datetime.fromisoformat(r[7]), value=None if r[8] is None else json.loads(r[8]),
            source=r[9], annotator=r[10], flags=json.loads(r[11]),
        )  # fmt: skip

    def history(self, kind: str, key: str) -> builtins.list[Change]:
        """Every change of one label, oldest first (including automatic proposals not applied)."""
        with self._connect() as con:
            rows = con.execute(self._CHANGE_SQL + " WHERE kind = ? AND key = ? ORDER BY id", (kind, key)).fetchall()
        return [self._change(r) for r in rows]

    def histories(self, kind: str) -> dict[str, builtins.list[Change]]:
        """:meth:`history` of every label of one kind at once: ``{key: [Change, ...]}``."""
        out: dict[str, builtins.list[Change]] = {}
        with self._connect() as con:
            for r in con.execute(self._CHANGE_SQL + " WHERE kind = ? ORDER BY id", (kind,)):
                out.setdefault(r[2], []).append(self._change(r))
        return out

    def opinions(self, kind: str, key: str) -> dict[str, Change]:
        """Each human annotator's latest value for one label since its last review (:func:`opinions`)."""
        return opinions(self.history(kind, key))

    # -- writing -----------------------------------------------------------------------------
    def put(
        self,
        kind: str,
        key: str,
        value: dict[str, Any],
        *,
        source: Source,
        annotator: str,
        expected_version: int | None = None,
        flags: tuple[str, ...] | builtins.list[str] = (),
    ) -> Label:
        """Set a label; return its state afterwards.

        Parameters
        ----------
        kind, key, value
            As in the module table; ``value`` is validated and normalised (azimuth wrapped to
            [-180, 180), heading yaw to [-180, 180)).
        source : {"auto", "annotator", "reviewed"}
        annotator : str
            Who (or which program, e.g. ``"align"``) made the value.
        expected_version : int, optional
            The version the caller's edit was based on (0: "I saw no label"). None writes
            whatever the current version is (programs, not interactive editors).
        flags : sequence of str
            Review flags (e.g. ``"ambiguous"``, ``"disagreement"``).

        Raises
        ------
        LabelConflict
            ``expected_version`` is not the current version; nothing was written.
        InputError
            Invalid kind, key, value, source or annotator.
        """
        value = validate_value(kind, key, value)
        if source not in ("auto", "annotator", "reviewed"):
            raise InputError(f"label source {source!r}: not one of auto, annotator, reviewed")
        check_name(annotator)
        flags = sorted({check_name(f, "flag") for f in flags})
        with self._connect() as con, self._write(con):
            if source == "reviewed":
                self._require_reviewer(con, annotator)
            return self._put_tx(con, kind, key, value, source, annotator, expected_version, flags)

    def _put_tx(self, con, kind, key, value, source, annotator, expected_version, flags) -> Label:
        value_json, flags_json = json.dumps(value, sort_keys=True), json.dumps(flags)
        row = self._current(con, kind, key)
        version = row[2] if row else 0
        current = self._label(row) if row else None
        if expected_version is not None and expected_version != version:
            raise LabelConflict(kind, key, expected_version, current, version)
        if current is not None and (value_json, source, annotator, flags_json) == (
            json.dumps(current.value, sort_keys=True), current.source, current.annotator, json.dumps(current.flags)
        ):  # fmt: skip
            return current
        if source == "auto" and current is not None and current.source in HUMAN_SOURCES:
            con.execute(
                "INSERT INTO events (kind, key, op, applied, version, actor, time, value, source, annotator, flags)"
                " VALUES (?, ?, 'kept', 0, ?, ?, ?, ?, ?, ?, ?)",
                (kind, key, version, annotator, _now(), value_json, source, annotator, flags_json),
            )
            return current
        self._apply(con, kind, key, version + 1, "put", annotator, value_json, source, annotator, flags_json,
                    parent=row[8] if row else None)  # fmt: skip
        return cast(Label, self._label(cast(tuple, self._current(con, kind, key))))  # the row just written

    def undo(self, kind: str, key: str, annotator: str, *, expected_version: int | None = None) -> Label | None:
        """Restore the state before the label's last applied change; return it (None: absent).

        Repeated undos walk further back. The undo is itself a change (new version, in history).

        Raises
        ------
        InputError
            Nothing to undo.
        LabelConflict
            ``expected_version`` given and not current.
        """
        check_name(annotator)
        with self._connect() as con, self._write(con):
            row = self._current(con, kind, key)
            version = row[2] if row else 0
            if expected_version is not None and expected_version != version:
                raise LabelConflict(kind, key, expected_version, self._label(row) if row else None, version)
            if row is None or (row[3] is None and row[9] is None):
                raise InputError(f"{kind} {key}: nothing to undo")
            parent = row[9]
            if parent is None:  # the label did not exist before its first change: remove it
                restored = (None, None, None, "[]", None)
            else:
                restored = con.execute(
                    "SELECT value, source, annotator, flags, parent FROM events WHERE id = ?", (parent,)
                ).fetchone()
            value_json, source, author, flags_json, grandparent = restored
            self._apply(con, kind, key, version + 1, "undo", annotator, value_json, source, author, flags_json,
                        parent=grandparent)  # fmt: skip
            return self._label(cast(tuple, self._current(con, kind, key)))  # the row just written

    def _apply(self, con, kind, key, version, op, actor, value_json, source, author, flags_json, *, parent) -> None:
        cur = con.execute(
            "INSERT INTO events (kind, key, op, applied, version, actor, time, value, source, annotator, flags, parent)"
            " VALUES (?, ?, ?, 1, ?, ?, ?, ?, ?, ?, ?, ?)",
            (kind, key, op, version, actor, _now(), value_json, source, author, flags_json, parent),
        )
        if _mid_write_hook is not None:
            _mid_write_hook()
        con.execute(
            "INSERT INTO labels (kind, key, version, event) VALUES (?, ?, ?, ?) "
            "ON CONFLICT (kind, key) DO UPDATE SET version = excluded.version, event = excluded.event",
            (kind, key, version, cur.lastrowid),
        )

    # -- team: users, assignments, verdicts, notes --------------------------------------------
    def _require_reviewer(self, con: sqlite3.Connection, name: str) -> None:
        """Once users exist, only a registered reviewer may write ``reviewed`` or a verdict."""
        if not self._team or con.execute("SELECT COUNT(*) FROM users").fetchone()[0] == 0:
            return
        row = con.execute("SELECT role FROM users WHERE name = ?", (name,)).fetchone()
        if row is None or row[0] != "reviewer":
            raise InputError(f"{name!r} is not a reviewer: only reviewers mark labels reviewed")

    def _rows(self, sql: str, args: tuple = ()) -> builtins.list[tuple]:
        if not self._team:  # a schema-1 store opened read-only: no team tables yet
            return []
        with self._connect() as con:
            return con.execute(sql, args).fetchall()

    def add_user(self, name: str, role: str) -> None:
        """Register ``name`` with ``role`` (``annotator`` or ``reviewer``); an existing user gets the new role."""
        check_name(name, "user name")
        if role not in ROLES:
            raise InputError(f"role {role!r}: not one of {', '.join(ROLES)}")
        with self._connect() as con, self._write(con):
            con.execute(
                "INSERT INTO users VALUES (?, ?, ?) ON CONFLICT (name) DO UPDATE SET role = excluded.role",
                (name, role, _now()),
            )

    def setting(self, name: str) -> str | None:
        """A campaign setting kept in the store (``blind``: ``"1"`` hides other labels from annotators)."""
        with self._connect() as con:
            row = con.execute("SELECT value FROM meta WHERE name = ?", (f"setting.{name}",)).fetchone()
        return row[0] if row else None

    def set_setting(self, name: str, value: str) -> None:
        with self._connect() as con, self._write(con):
            con.execute(
                "INSERT INTO meta VALUES (?, ?) ON CONFLICT (name) DO UPDATE SET value = excluded.value",
                (f"setting.{name}", value),
            )

    def users(self) -> dict[str, str]:
        """``{name: role}`` of the registered users (empty: a campaign without a team)."""
        return dict(self._rows("SELECT name, role FROM users ORDER BY name"))

    def assign(self, kind: str, plan: dict[str, builtins.list[str]]) -> int:
        """Replace the assignment of task ``kind``: ``plan`` maps each item key to its annotators
        (registered users). Returns the number of (item, annotator) pairs stored."""
        users = self.users()
        for names in plan.values():
            for n in names:
                if n not in users:
                    raise InputError(f"{n!r} is not a user (add it with `solidkit label users add {n}`)")
        with self._connect() as con, self._write(con):
            con.execute("DELETE FROM assignments WHERE kind = ?", (kind,))
            con.executemany(
                "INSERT OR IGNORE INTO assignments VALUES (?, ?, ?)",
                [(kind, key, n) for key, names in plan.items() for n in names],
            )
        return sum(len(set(v)) for v in plan.values())

    def assignments(self, kind: str | None = None) -> dict[tuple[str, str], builtins.list[str]]:
        """``{(kind, key): [annotator, ...]}`` (empty: every annotator labels every item)."""
        where, args = (" WHERE kind = ?", (kind,)) if kind else ("", ())
        out: dict[tuple[str, str], builtins.list[str]] = {}
        for k, key, n in self._rows(
            "SELECT kind, key, annotator FROM assignments" + where + " ORDER BY annotator", args
        ):
            out.setdefault((k, key), []).append(n)
        return out

    def review(
        self,
        kind: str,
        key: str,
        annotator: str,
        verdict: Literal["accept", "reject"],
        comment: str,
        *,
        reviewer: str,
        expected_version: int | None = None,
    ) -> tuple[Verdict, Label | None]:
        """Accept or reject ``annotator``'s current value of a label (one transaction).

        Accept stores that value as ``reviewed`` by ``reviewer`` (the label is settled); reject
        leaves the label as it is and sends the item back to the annotator with ``comment``.

        Raises
        ------
        InputError
            ``reviewer`` not a reviewer, ``annotator`` has no value, bad verdict or comment.
        LabelConflict
            Accept with ``expected_version`` not current.
        """
        check_name(reviewer, "reviewer")
        if verdict not in ("accept", "reject"):
            raise InputError(f"verdict {verdict!r}: accept or reject")
        if not isinstance(comment, str) or len(comment) > MAX_COMMENT:
            raise InputError(f"comment: text of at most {MAX_COMMENT} characters")
        with self._connect() as con, self._write(con):
            self._require_reviewer(con, reviewer)
            rows = con.execute(self._CHANGE_SQL + " WHERE kind = ? AND key = ? ORDER BY id", (kind, key)).fetchall()
            mine = opinions([self._change(r) for r in rows], since_review=False).get(annotator)
            if mine is None or mine.value is None:
                raise InputError(f"{kind} {key}: {annotator!r} has no value to review")
            label = None
            if verdict == "accept":
                label = self._put_tx(con, kind, key, mine.value, "reviewed", reviewer, expected_version, [])
            cur = con.execute(
                "INSERT INTO verdicts (kind, key, event, annotator, verdict, comment, reviewer, time)"
                " VALUES (?, ?, ?, ?, ?, ?, ?, ?)",
                (kind, key, mine.id, annotator, verdict, comment.strip(), reviewer, _now()),
            )
            row = con.execute("SELECT * FROM verdicts WHERE id = ?", (cur.lastrowid,)).fetchone()
        return self._verdict(row), label

    @staticmethod
    def _verdict(r: tuple) -> Verdict:
        return Verdict(id=r[0], kind=r[1], key=r[2], event=r[3], annotator=r[4], verdict=r[5], comment=r[6],
                       reviewer=r[7], time=datetime.fromisoformat(r[8]))  # fmt: skip

    def verdicts(self, kind: str | None = None) -> builtins.list[Verdict]:
        """Every verdict (of one kind), oldest first."""
        where, args = (" WHERE kind = ?", (kind,)) if kind else ("", ())
        return [self._verdict(r) for r in self._rows("SELECT * FROM verdicts" + where + " ORDER BY id", args)]

    def put_note(self, kind: str, key: str, annotator: str, text: str, *, skip: bool = False) -> Note:
        """Set ``annotator``'s note on an item (``skip``: "can't tell", ``text`` the reason; an
        empty text without skip clears the note)."""
        check_name(annotator)
        if kind not in _KEYS or not isinstance(key, str) or not _KEYS[kind].match(key):
            raise InputError(f"note on {kind} {key!r}: no such label address")
        if not isinstance(text, str) or len(text) > MAX_COMMENT or not _finite_text(text):
            raise InputError(f"note: text of at most {MAX_COMMENT} printable characters")
        if skip and not text.strip():
            raise InputError("skip: say why (what makes it impossible to tell)")
        with self._connect() as con, self._write(con):
            con.execute(
                "INSERT INTO notes (kind, key, annotator, skip, text, time) VALUES (?, ?, ?, ?, ?, ?)",
                (kind, key, annotator, int(bool(skip)), text.strip(), _now()),
            )
        return Note(kind=kind, key=key, annotator=annotator, skip=bool(skip), text=text.strip(),
                    time=datetime.now(timezone.utc))  # fmt: skip

    def notes(self, kind: str | None = None) -> dict[tuple[str, str, str], Note]:
        """Each annotator's latest note per item: ``{(kind, key, annotator): Note}`` (cleared ones left out)."""
        where, args = (" WHERE kind = ?", (kind,)) if kind else ("", ())
        out: dict[tuple[str, str, str], Note] = {}
        for k, key, who, skip, text, time in self._rows(
            "SELECT kind, key, annotator, skip, text, time FROM notes" + where + " ORDER BY id", args
        ):
            if skip or text:
                out[(k, key, who)] = Note(kind=k, key=key, annotator=who, skip=bool(skip), text=text,
                                          time=datetime.fromisoformat(time))  # fmt: skip
            else:
                out.pop((k, key, who), None)
        return out

    # -- export ------------------------------------------------------------------------------
    def export(self) -> dict[str, Any]:
        """All current labels as a JSON-able document (for the test-set builder).

        Returns
        -------
        dict
            ``{"format": "solidkit.labels", "schema_version", "conventions_version", "campaign",
            "exported_at", "counts": {kind: {source: n}}, "labels": [Label as JSON, ...]}``;
            each label also lists ``annotators`` (every human who set a value for it).
        """
        labels = self.list()
        with self._connect() as con:
            rows = con.execute(
                "SELECT DISTINCT kind, key, annotator FROM events "
                "WHERE applied = 1 AND op = 'put' AND source IN ('annotator', 'reviewed') ORDER BY id"
            ).fetchall()
        humans: dict[tuple[str, str], builtins.list[str]] = {}
        for kind, key, who in rows:
            humans.setdefault((kind, key), []).append(who)
        counts: dict[str, dict[str, int]] = {}
        out = []
        for lab in labels:
            counts.setdefault(lab.kind, {}).setdefault(lab.source, 0)
            counts[lab.kind][lab.source] += 1
            out.append({**lab.model_dump(mode="json"), "annotators": humans.get((lab.kind, lab.key), [])})
        return {
            "format": "solidkit.labels",
            "schema_version": self.schema_version,
            "conventions_version": CONVENTIONS_VERSION,
            "campaign": self.campaign_dir.resolve().name,
            "exported_at": _now(),
            "counts": counts,
            "labels": out,
            "users": self.users(),
            "verdicts": [v.model_dump(mode="json") for v in self.verdicts()],
            "notes": [n.model_dump(mode="json") for n in self.notes().values()],
        }

    def check(self) -> builtins.list[str]:
        """Consistency problems (empty when healthy): SQLite's integrity check and that each
        label points at an applied event of its own with its version."""
        problems = []
        with self._connect() as con:
            problems += [r[0] for r in con.execute("PRAGMA integrity_check").fetchall() if r[0] != "ok"]
            bad = con.execute(
                "SELECT l.kind, l.key FROM labels l LEFT JOIN events e ON e.id = l.event "
                "WHERE e.id IS NULL OR e.kind != l.kind OR e.key != l.key OR e.version != l.version OR e.applied = 0 "
                "OR e.id != (SELECT MAX(id) FROM events x WHERE x.kind = l.kind AND x.key = l.key AND x.applied = 1)"
            ).fetchall()
            problems += [f"{k} {key}: label row does not match its last applied change" for k, key in bad]
        return problems
