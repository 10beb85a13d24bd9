"""The labeling web app: a FastAPI server for the static page in ``static/``.

Security model
--------------
- **Files.** Only images the campaign index lists are served, by opaque id; their paths were
  resolved (symlinks followed) and checked to lie inside the campaign. The page's own files come
  from the package's ``static/`` folder (Starlette's ``StaticFiles``: no traversal, no symlinks
  out). Anything else is 404.
- **Writes** go to the label store only (and the image cache under ``labels/``), through
  :class:`PutBody`, :class:`UndoBody`, :class:`VerdictBody`, :class:`NoteBody` (pydantic, strict,
  extra fields refused, values checked per kind), bodies over
  :data:`MAX_BODY_BYTES` refused with 413.
- **Cross-site requests.** Every state-changing request must carry the header
  ``X-Solidkit: 1`` (a cross-site form or image cannot; a cross-site script would need a CORS
  preflight, which this server never grants), must not come from another origin (``Origin``,
  ``Sec-Fetch-Site``), and the ``Host`` header must name this server (DNS rebinding).
- **Identity.** Everyone logs in with a name (``POST /api/session``): a registered user of the
  label store once it has users, any valid name (an annotator) before. The session (an
  ``HttpOnly``, ``SameSite=Strict`` cookie, kept in memory: a restart logs everyone out) says who
  saves; a body never names its author. Only reviewers write ``reviewed`` labels and verdicts and
  read the review queue, the agreement and the export. An annotator sees only their assigned
  items; blind, the server leaves every other person's value out of what it sends them.
- **Token mode** (any bind address other than loopback): the token goes with the name in the
  login body, never in a URL; five wrong tokens per address and minute, then 429 for the rest of
  it. Scripts may send ``Authorization: Bearer TOKEN`` with ``X-Solidkit-User: NAME``. Every
  ``/api`` route except the session exchange answers 401 without a session.
- **Values** are checked strictly (:class:`SunEdit`, :class:`PixelEdit`, :class:`HeadingEdit`):
  JSON numbers only (no ``"5"``, no ``true``), finite, in range, a probe pixel inside its photo.
"""

from __future__ import annotations

import base64
import hashlib
import hmac
import math
import re
import secrets
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal, cast

from fastapi import Depends, FastAPI, HTTPException, Query, Request
from fastapi.responses import FileResponse, JSONResponse, Response
from fastapi.staticfiles import StaticFiles
from pydantic import BaseModel, ConfigDict, Field, ValidationError
from starlette.middleware.trustedhost import TrustedHostMiddleware

from solidkit.errors import InputError, validation_message
from solidkit.labeling.images import PREVIEW_WIDTH, ImageService, tile_grid
from solidkit.labeling.review import (
    THRESHOLDS,
    UNITS,
    agreement,
    disagreement_flag,
    own_values,
    review_all,
    review_item,
    user_status,
)
from solidkit.labeling.store import LabelConflict, LabelStore, check_name, validate_value
from solidkit.labeling.tasks import TASKS, CampaignIndex

__all__ = ["create_app", "MAX_BODY_BYTES", "LOOPBACK_HOSTS", "PutBody", "UndoBody", "LOGIN_LIMIT"]

STATIC = Path(__file__).parent / "static"
MAX_BODY_BYTES = 16 * 1024
LOOPBACK_HOSTS = ("127.0.0.1", "localhost", "::1", "[::1]")
SESSION_COOKIE = "solidkit_session"
LOGIN_LIMIT = (5, 60.0)  # wrong tokens per client address, window in seconds: then 429 until it passes
_IMG_ID = r"^img-[0-9a-f]{16}$"
_UNSAFE = {"POST", "PUT", "PATCH", "DELETE"}
_KIND = Literal["sun", "probe_pixel", "heading"]
# flag codes a blind annotator may see (align's own); disagreement flags tell the other's answer
_BLIND_HIDDEN_FLAGS = ("annotators_disagree", "differs_from_auto")


class _Body(BaseModel):
    model_config = ConfigDict(extra="forbid", strict=True)


class SunEdit(_Body):
    """A sun mark as the page sends it (degrees, conventions §3)."""

    found: bool
    azimuth_deg: float | None = Field(None, ge=-180.0, le=180.0, allow_inf_nan=False)
    elevation_deg: float | None = Field(None, ge=-90.0, le=90.0, allow_inf_nan=False)
    uncertainty_deg: float | None = Field(None, ge=0.0, le=45.0, allow_inf_nan=False)


class PixelEdit(_Body):
    """A probe pixel (full-resolution photo pixels; the bounds come from the photo's size)."""

    x: float = Field(allow_inf_nan=False)
    y: float = Field(allow_inf_nan=False)


class HeadingEdit(_Body):
    yaw_deg: float = Field(ge=-180.0, le=180.0, allow_inf_nan=False)


_EDITS: dict[str, type[_Body]] = {"sun": SunEdit, "probe_pixel": PixelEdit, "heading": HeadingEdit}


class PutBody(_Body):
    """A label edit from the page; who makes it comes from the session, never from the body."""

    kind: _KIND
    key: str = Field(max_length=200)
    value: dict[str, Any]
    expected_version: int = Field(ge=0, description="the version the edit was based on (0: no label seen)")
    source: Literal["annotator", "reviewed"] = "annotator"
    blind: bool = False


class UndoBody(_Body):
    kind: _KIND
    key: str = Field(max_length=200)
    expected_version: int = Field(ge=0)


class VerdictBody(_Body):
    kind: _KIND
    key: str = Field(max_length=200)
    annotator: str = Field(min_length=1, max_length=64)
    verdict: Literal["accept", "reject"]
    comment: str = Field("", max_length=500)
    expected_version: int | None = Field(None, ge=0)


class NoteBody(_Body):
    kind: _KIND
    key: str = Field(max_length=200)
    text: str = Field("", max_length=500)
    skip: bool = False


class SessionBody(_Body):
    token: str = Field("", max_length=256)
    name: str = Field(min_length=1, max_length=64)


class LogoutBody(_Body):
    pass


@dataclass(frozen=True)
class User:
    name: str
    role: str


def _csp(index_html: str) -> str:
    """Content-Security-Policy allowing the page's one inline script (the import map) by hash."""
    hashes = [
        "'sha256-" + base64.b64encode(hashlib.sha256(m.encode()).digest()).decode() + "'"
        for m in re.findall(r"<script type=\"importmap\">(.*?)</script>", index_html, flags=re.S)
    ]
    return (
        "default-src 'self'; script-src 'self' " + " ".join(hashes) + "; style-src 'self' 'unsafe-inline'; "
        "img-src 'self' blob: data:; connect-src 'self'; worker-src 'self' blob:; object-src 'none'; "
        "base-uri 'none'; form-action 'self'; frame-ancestors 'none'"
    )


def create_app(
    campaign_dir: str | Path,
    *,
    alignment: dict[str, Any] | None = None,
    token: str | None = None,
    allowed_hosts: list[str] | None = None,
    image_cache: str | Path | None = None,
    warm_cache: bool = False,
) -> FastAPI:
    """Build the app for one campaign.

    Parameters
    ----------
    campaign_dir : path
        The campaign (manifest, products; the label store is created in ``labels/``).
    alignment : dict, optional
        ``align/alignment.json`` as a dict (automatic proposals), or None.
    token : str, optional
        Require this token (token mode). None: no token (loopback only; the CLI enforces that).
        Either way every annotator logs in with a name: a registered user once the store has
        users (``solidkit label users add``), any name (role annotator) before.
    allowed_hosts : list of str, optional
        Host names the ``Host`` header may carry (default: the loopback names).
    image_cache : path, optional
        Folder for the encoded previews and tiles (default ``CAMPAIGN/labels/image-cache``).
    warm_cache : bool
        Make every image's preview and tiles in a background thread from the start (heading
        panoramas first), so that first views come from the disk cache.
    """
    index = CampaignIndex(campaign_dir, alignment)
    store = LabelStore(index.root)
    images = ImageService(cache_dir=Path(image_cache) if image_cache else index.root / "labels" / "image-cache")
    sessions: dict[str, str] = {}  # session id -> user name (in memory: a restart logs everyone out)
    failures: dict[str, list[float]] = {}  # client address -> times of wrong tokens
    failures_lock = threading.Lock()
    index_html = (STATIC / "index.html").read_text(encoding="utf-8")
    csp = _csp(index_html)

    app = FastAPI(title="solidkit labeling", docs_url=None, redoc_url=None, openapi_url=None)
    app.state.index, app.state.store, app.state.images = index, store, images
    app.state.sessions = sessions
    app.state.warm_done = threading.Event()
    if warm_cache:
        heading = [index.images[i.view["image"]] for i in index.items["heading"].values() if i.view.get("image")]
        order = list(dict.fromkeys([*heading, *index.images.values()]))

        def _warm() -> None:
            images.warm(order)
            app.state.warm_done.set()

        threading.Thread(target=_warm, name="image-cache", daemon=True).start()

    # -- middleware (outermost last) ---------------------------------------------------------
    @app.middleware("http")
    async def guard(request: Request, call_next):
        if request.method in _UNSAFE:
            if request.headers.get("x-solidkit") != "1":
                return JSONResponse({"detail": "missing X-Solidkit header"}, status_code=403)
            origin = request.headers.get("origin")
            host = request.headers.get("host", "")
            if origin is not None and origin not in (f"http://{host}", f"https://{host}"):
                return JSONResponse({"detail": "cross-origin request refused"}, status_code=403)
            if request.headers.get("sec-fetch-site", "same-origin") not in ("same-origin", "none"):
                return JSONResponse({"detail": "cross-site request refused"}, status_code=403)
            length = request.headers.get("content-length")
            if length is None or not length.isdigit() or int(length) > MAX_BODY_BYTES:
                return JSONResponse({"detail": f"request body missing or over {MAX_BODY_BYTES} bytes"}, status_code=413)
        response = await call_next(request)
        response.headers["X-Content-Type-Options"] = "nosniff"
        response.headers["Referrer-Policy"] = "no-referrer"
        response.headers["X-Frame-Options"] = "DENY"
        response.headers["Content-Security-Policy"] = csp
        response.headers["Cross-Origin-Opener-Policy"] = "same-origin"
        response.headers["Cross-Origin-Resource-Policy"] = "same-origin"
        if request.url.path.startswith("/api/") and "cache-control" not in response.headers:
            response.headers["Cache-Control"] = "no-store"
        return response

    app.add_middleware(TrustedHostMiddleware, allowed_hosts=list(allowed_hosts or LOOPBACK_HOSTS))

    def _role(name: str) -> str | None:
        users = store.users()
        if not users:  # no team registered: everyone is an annotator
            return "annotator"
        return users.get(name)

    def _token_ok(request: Request) -> bool:
        if token is None:
            return True
        bearer = request.headers.get("authorization", "")
        return bearer.startswith("Bearer ") and hmac.compare_digest(bearer[7:].encode(), token.encode())

    def _session_user(request: Request) -> User | None:
        sid = request.cookies.get(SESSION_COOKIE)
        name = sessions.get(sid) if sid else None  # a 256-bit random id: a plain lookup leaks nothing useful
        if name is None and _token_ok(request) and request.headers.get("x-solidkit-user"):
            name = request.headers["x-solidkit-user"]  # scripts: Bearer token (if any) + a user name
        role = _role(name) if name else None
        return User(name, role) if name and role else None

    def auth(request: Request) -> User:
        user = _session_user(request)
        if user is None:
            raise HTTPException(401, "log in: open the page and enter your name (and the token, if one is required)")
        return user

    def reviewer(user: User = Depends(auth)) -> User:
        if user.role != "reviewer":
            raise HTTPException(403, f"{user.name} is an annotator: only reviewers review labels")
        return user

    def is_blind(user: User, asked: bool) -> bool:
        return user.role != "reviewer" and (asked or store.setting("blind") == "1")

    # -- page --------------------------------------------------------------------------------
    @app.get("/", include_in_schema=False)
    def page() -> FileResponse:
        return FileResponse(STATIC / "index.html", headers={"Cache-Control": "no-cache"})

    app.mount("/static", StaticFiles(directory=STATIC, follow_symlink=False), name="static")

    # -- session -----------------------------------------------------------------------------
    @app.get("/api/session")
    def session_state(request: Request) -> dict:
        user = _session_user(request)
        team = store.users()
        return {
            "token_required": token is not None,
            "authenticated": user is not None,
            "user": {"name": user.name, "role": user.role} if user else None,
            "team": bool(team),
            "users": sorted(team) if (token is None or user is not None) else [],
        }

    def _limited(client: str) -> float:
        now = time.monotonic()
        with failures_lock:
            recent = [t for t in failures.get(client, []) if now - t < LOGIN_LIMIT[1]]
            failures[client] = recent
        return LOGIN_LIMIT[1] - (now - recent[0]) if len(recent) >= LOGIN_LIMIT[0] else 0.0

    @app.post("/api/session")
    def login(body: SessionBody, request: Request) -> Response:
        client = request.client.host if request.client else "?"
        wait = _limited(client)
        if wait > 0:
            raise HTTPException(
                429, f"too many wrong tokens: wait {math.ceil(wait)} s", {"Retry-After": str(math.ceil(wait))}
            )
        if token is not None and not hmac.compare_digest(body.token.encode(), token.encode()):
            with failures_lock:
                failures.setdefault(client, []).append(time.monotonic())
            raise HTTPException(401, "wrong token")
        name = body.name.strip()
        role = _role(name)
        if role is None:
            raise HTTPException(403, f"{name!r} is not a user of this campaign (`solidkit label users add {name}`)")
        try:
            check_name(name)
        except InputError as exc:
            raise HTTPException(422, str(exc)) from None
        sid = secrets.token_urlsafe(32)
        sessions[sid] = name
        resp = JSONResponse({"authenticated": True, "user": {"name": name, "role": role}})
        resp.set_cookie(SESSION_COOKIE, sid, httponly=True, samesite="strict", path="/")
        return resp

    @app.post("/api/logout")
    def logout(body: LogoutBody, request: Request) -> Response:
        sessions.pop(request.cookies.get(SESSION_COOKIE, ""), None)
        resp = JSONResponse({"authenticated": False})
        resp.delete_cookie(SESSION_COOKIE, path="/")
        return resp

    # -- campaign and queues -----------------------------------------------------------------
    def _allowed(user: User, kind: str) -> set[str] | None:
        """Keys ``user`` labels in task ``kind`` (None: all; reviewers and unassigned tasks)."""
        if user.role == "reviewer":
            return None
        plan = store.assignments(kind)
        if not plan:
            return None
        return {key for (_, key), names in plan.items() if user.name in names}

    def _rows(user: User, kind: str) -> list[dict]:
        reviews = review_all(index, store, (kind,))
        if user.role == "reviewer":
            return [{"kind": kind, "key": r.key, "status": r.status, "flags": r.flags} for r in reviews]
        allowed = _allowed(user, kind)
        labels = {lab.key: lab for lab in store.list(kind)}
        histories = store.histories(kind)
        verdicts = [v for v in store.verdicts(kind) if v.annotator == user.name]
        notes = store.notes(kind)
        out = []
        for r in reviews:
            if allowed is not None and r.key not in allowed:
                continue
            it = index.items[kind][r.key]
            st = user_status(it, labels.get(r.key), histories.get(r.key, []), user.name,
                             [v for v in verdicts if v.key == r.key], notes.get((kind, r.key, user.name)))  # fmt: skip
            out.append({"kind": kind, "key": r.key, "flags": list(it.flags)} | st)
        return out

    def progress(user: User) -> dict:
        out = {}
        for kind in TASKS:
            rows = _rows(user, kind)
            out[kind] = {s: sum(r["status"] == s for r in rows) for s in ("done", "flagged", "left", "returned")}
            out[kind]["total"] = len(rows)
        if user.role == "reviewer":
            reviews = review_all(index, store)
            out["review"] = {"open": sum(bool(r.flags) and r.status != "done" or r.open_disagreement for r in reviews)}
        return out

    @app.get("/api/campaign")
    def campaign(user: User = Depends(auth)) -> dict:
        return {
            "name": index.root.name,
            "scenes": [s.id for s in index.manifest.scenes],
            "progress": progress(user),
            "problems": index.problems,
            "thresholds": {k: {"value": v, "unit": UNITS[k]} for k, v in THRESHOLDS.items()},
            "has_alignment": bool(index.alignment),
            "user": {"name": user.name, "role": user.role},
            "blind_forced": store.setting("blind") == "1" and user.role != "reviewer",
            "team": bool(store.users()),
        }

    @app.get("/api/queue/{kind}")
    def queue(kind: Literal["sun", "probe_pixel", "heading", "review"], user: User = Depends(auth)) -> dict:
        if kind == "review":
            if user.role != "reviewer":
                raise HTTPException(403, "the review queue is for reviewers")
            notes = store.notes()
            verdicts = store.verdicts()
            rows = [
                r for r in review_all(index, store)
                if r.flags or r.open_disagreement or r.opinions or any(k[:2] == (r.kind, r.key) for k in notes)
            ]  # fmt: skip
            order = {"flagged": 0, "left": 1, "done": 2}
            # biggest first, in units of each kind's threshold (degrees and pixels do not compare)
            rows.sort(
                key=lambda r: (
                    not r.open_disagreement,
                    order[r.status],
                    -(r.disagreement or r.vs_auto or 0.0) / THRESHOLDS[r.kind],
                )
            )
            items = [
                r.as_dict()
                | {
                    "title": index.items[r.kind][r.key].title,
                    "notes": {k[2]: n.model_dump(mode="json") for k, n in notes.items() if k[:2] == (r.kind, r.key)},
                    "verdicts": [v.model_dump(mode="json") for v in verdicts if (v.kind, v.key) == (r.kind, r.key)],
                }
                for r in rows
            ]
        else:
            items = [row | {"title": index.items[kind][row["key"]].title} for row in _rows(user, kind)]
        return {"kind": kind, "items": items, "progress": progress(user)}

    def _item(kind: str, key: str):
        try:
            return index.item(kind, key)
        except KeyError:
            raise HTTPException(404, f"no {kind} item {key!r}") from None

    def _image_info(img_id: str) -> dict:
        ref = index.images[img_id]
        w, h = images.size(ref)
        info = {"id": img_id, "width": w, "height": h, "layout": ref.layout, "hdr": ref.hdr,
                "preview_width": min(w, PREVIEW_WIDTH)}  # fmt: skip
        if ref.layout == "equirect":
            cols, rows = tile_grid(w)
            info["tiles"] = {"cols": cols, "rows": rows}
        return info

    def _mine(kind: str, key: str, user: User, history: list, label) -> dict | None:
        ch = own_values(history).get(user.name)
        if ch is None:
            return None
        rejects = [v for v in store.verdicts(kind) if v.key == key and v.event == ch.id and v.annotator == user.name]
        return {
            "value": ch.value, "time": ch.time.isoformat(),
            "verdict": rejects[-1].model_dump(mode="json") if rejects else None,
        }  # fmt: skip

    @app.get("/api/item")
    def item(kind: _KIND, key: str = Query(max_length=200), blind: bool = False, user: User = Depends(auth)) -> dict:
        it = _item(kind, key)
        allowed = _allowed(user, kind)
        if allowed is not None and key not in allowed:
            raise HTTPException(403, f"{kind} {key} is assigned to other annotators")
        hide = is_blind(user, blind)
        label = store.get(kind, key)
        history = store.history(kind, key)
        view, proposal = dict(it.view), it.proposal
        if proposal is None:  # no alignment.json: align's auto label in the store (`solidkit label sun`)
            auto = next((c for c in reversed(history) if c.source == "auto" and c.value), None)
            if auto is not None:
                auto_value = cast("dict[str, Any]", auto.value)  # the search kept a change with a value
                proposal = {k: v for k, v in auto_value.items() if k in _EDITS[kind].model_fields}
                if kind == "sun":
                    view["candidates"] = view.get("candidates") or auto_value.get("candidates") or []
                if kind == "probe_pixel":
                    view["proposal_source"] = "align (geometry)"
        for name in ("image",):
            if view.get(name):
                view[name] = _image_info(view[name])
        if view.get("photo"):
            view["photo"] = view["photo"] | {"image": _image_info(view["photo"]["image"])}
        siblings = {}
        if kind == "probe_pixel":  # the scene's other probes, to show them all on the photo
            for other in index.items["probe_pixel"].values():
                if other.scene == it.scene:
                    if hide:
                        mine = own_values(store.history(kind, other.key)).get(user.name)
                        siblings[other.probe] = mine.value if mine else None
                    else:
                        lab = store.get(kind, other.key)
                        siblings[other.probe] = (lab.value if lab else None) or other.proposal
        review = review_item(it, label, history).as_dict()
        if hide:  # others' values hidden everywhere: label, proposal, history, opinions, flags
            proposal, label = None, None
            history = [c for c in history if c.actor == user.name]
            view = view | {"candidates": [], "cues": {}, "residual_deg": None, "geometry": None,
                           "geometry_error_px": None}  # fmt: skip
            review = review | {
                "opinions": {n: o for n, o in review["opinions"].items() if n == user.name},
                "flags": [f for f in review["flags"] if not f.startswith(_BLIND_HIDDEN_FLAGS)],
                "disagreement": None, "vs_auto": None, "open_disagreement": False, "label": None,
            }  # fmt: skip
        notes = store.notes(kind)
        note = notes.get((kind, key, user.name))
        return {
            "kind": kind, "key": key, "title": it.title, "scene": it.scene, "probe": it.probe, "view": view,
            "proposal": proposal, "flags": it.flags, "siblings": siblings, "blind": hide,
            "label": label.model_dump(mode="json") if label else None, "version": store.version(kind, key),
            "review": review, "history": [c.model_dump(mode="json") for c in history[-30:]],
            "mine": _mine(kind, key, user, store.history(kind, key), label),
            "note": note.model_dump(mode="json") if note else None,
            "own": _own_for_review(kind, key, user),
            "notes": {k[2]: n.model_dump(mode="json") for k, n in notes.items() if k[1] == key}
            if user.role == "reviewer" else {},
        }  # fmt: skip

    def _own_for_review(kind: str, key: str, user: User) -> dict:
        """For reviewers: each annotator's own value with its verdicts (what accept/reject act on)."""
        if user.role != "reviewer":
            return {}
        verdicts = [v for v in store.verdicts(kind) if v.key == key]
        out = {}
        for who, ch in own_values(store.history(kind, key)).items():
            vs = [v for v in verdicts if v.annotator == who and v.event == ch.id]
            out[who] = {"value": ch.value, "time": ch.time.isoformat(),
                        "verdict": vs[-1].model_dump(mode="json") if vs else None}  # fmt: skip
        return out

    # -- writes ------------------------------------------------------------------------------
    def _conflict(exc: LabelConflict) -> JSONResponse:
        cur = exc.current.model_dump(mode="json") if exc.current else None
        return JSONResponse({"detail": str(exc), "current": cur, "version": exc.current_version}, status_code=409)

    def _checked_value(kind: str, key: str, value: dict[str, Any]) -> dict[str, Any]:
        try:
            edit = _EDITS[kind].model_validate(value, strict=True)
        except ValidationError as exc:
            raise HTTPException(422, f"{kind} {key}: {validation_message(exc)}") from None
        out = edit.model_dump(exclude_none=kind != "sun")
        if kind == "probe_pixel":  # inside the photo: [-0.5, W - 0.5] x [-0.5, H - 0.5] (pixel edges)
            w, h = images.size(index.images[index.items[kind][key].view["photo"]["image"]])
            if not (-0.5 <= out["x"] <= w - 0.5 and -0.5 <= out["y"] <= h - 0.5):
                raise HTTPException(422, f"{kind} {key}: ({out['x']}, {out['y']}) lies outside the {w}x{h} photo")
        try:
            return validate_value(kind, key, out)
        except InputError as exc:
            raise HTTPException(422, str(exc)) from None

    def _writable(user: User, kind: str, key: str) -> None:
        _item(kind, key)
        allowed = _allowed(user, kind)
        if allowed is not None and key not in allowed:
            raise HTTPException(403, f"{kind} {key} is assigned to other annotators")

    @app.put("/api/label")
    def put_label(body: PutBody, user: User = Depends(auth)) -> Any:
        _writable(user, body.kind, body.key)
        if body.source == "reviewed" and user.role != "reviewer":
            raise HTTPException(403, f"{user.name} is an annotator: only reviewers store reviewed labels")
        value = _checked_value(body.kind, body.key, body.value)
        flags: list[str] = []
        hide = is_blind(user, body.blind)
        if body.source == "annotator":  # a second opinion far from the first is flagged for review
            flag = disagreement_flag(body.kind, user.name, value, store.history(body.kind, body.key))
            flags += [flag] if flag else []
        try:
            # blind: an independent opinion goes on top of whatever is there (a conflict dialog
            # would show the other's value); both stay in the history for the reviewer
            lab = store.put(body.kind, body.key, value, source=body.source, annotator=user.name,
                            expected_version=None if hide else body.expected_version, flags=flags)  # fmt: skip
        except LabelConflict as exc:
            return _conflict(exc)
        except InputError as exc:
            raise HTTPException(422, str(exc)) from None
        if hide:
            return {"label": None, "version": lab.version, "mine": {"value": value}}
        return {"label": lab.model_dump(mode="json"), "version": lab.version}

    @app.post("/api/undo")
    def undo(body: UndoBody, user: User = Depends(auth)) -> Any:
        _writable(user, body.kind, body.key)
        hist = store.history(body.kind, body.key)
        last = next((c for c in reversed(hist) if c.applied), None)
        hide = is_blind(user, False)
        if last is not None and last.actor != user.name and user.role != "reviewer":
            who = "someone else's" if hide else f"{last.actor}'s"
            raise HTTPException(403, f"the last change is {who}: only its author (or a reviewer) can undo it")
        try:
            lab = store.undo(body.kind, body.key, user.name, expected_version=body.expected_version)
        except LabelConflict as exc:
            if hide:  # the conflict would carry the other annotator's value
                return JSONResponse({"detail": "changed since you opened it", "current": None,
                                     "version": exc.current_version}, status_code=409)  # fmt: skip
            return _conflict(exc)
        except InputError as exc:
            raise HTTPException(422, str(exc)) from None
        if hide:
            return {"label": None, "version": store.version(body.kind, body.key)}
        return {"label": lab.model_dump(mode="json") if lab else None, "version": store.version(body.kind, body.key)}

    @app.post("/api/verdict")
    def verdict(body: VerdictBody, user: User = Depends(reviewer)) -> Any:
        _item(body.kind, body.key)
        if body.verdict == "reject" and not body.comment.strip():
            raise HTTPException(422, "reject: say what is wrong (the annotator sees the comment)")
        try:
            v, lab = store.review(body.kind, body.key, body.annotator, body.verdict, body.comment,
                                  reviewer=user.name, expected_version=body.expected_version)  # fmt: skip
        except LabelConflict as exc:
            return _conflict(exc)
        except InputError as exc:
            raise HTTPException(422, str(exc)) from None
        return {"verdict": v.model_dump(mode="json"), "label": lab.model_dump(mode="json") if lab else None,
                "version": store.version(body.kind, body.key)}  # fmt: skip

    @app.post("/api/note")
    def note(body: NoteBody, user: User = Depends(auth)) -> Any:
        _writable(user, body.kind, body.key)
        try:
            n = store.put_note(body.kind, body.key, user.name, body.text, skip=body.skip)
        except InputError as exc:
            raise HTTPException(422, str(exc)) from None
        return {"note": n.model_dump(mode="json")}

    @app.get("/api/agreement")
    def agreement_summary(user: User = Depends(reviewer)) -> dict:
        return agreement(index, store, TASKS)

    @app.get("/api/export")
    def export(user: User = Depends(auth)) -> dict:
        if user.role != "reviewer" and (store.users() or is_blind(user, False)):
            raise HTTPException(403, "the export shows every label: reviewers only")
        return store.export() | {"agreement": agreement(index, store, TASKS)}

    # -- pixels ------------------------------------------------------------------------------
    def _ref(img_id: str):
        if not re.match(_IMG_ID, img_id) or img_id not in index.images:
            raise HTTPException(404, "no such image")
        return index.images[img_id]

    _IMG_CACHE = {"Cache-Control": "private, max-age=86400"}

    @app.get("/api/img/{img_id}/preview.jpg", dependencies=[Depends(auth)])
    def preview(img_id: str) -> Response:
        return Response(images.preview(_ref(img_id)), media_type="image/jpeg", headers=_IMG_CACHE)

    @app.get("/api/img/{img_id}/tile/{col}/{row}.jpg", dependencies=[Depends(auth)])
    def tile(img_id: str, col: int, row: int) -> Response:
        ref = _ref(img_id)
        try:
            data = images.tile(ref, col, row)
        except KeyError:
            raise HTTPException(404, "no such tile") from None
        return Response(data, media_type="image/jpeg", headers=_IMG_CACHE)

    @app.get("/api/img/{img_id}/crop.jpg", dependencies=[Depends(auth)])
    def crop(
        img_id: str,
        x: float = Query(ge=-1e5, le=1e5), y: float = Query(ge=-1e5, le=1e5),  # noqa: E131
        w: float = Query(gt=0, le=1e5), h: float = Query(gt=0, le=1e5),
        out: int = Query(1024, ge=16, le=4096),
    ) -> Response:  # fmt: skip
        ref = _ref(img_id)
        try:
            data, box = images.crop(ref, x, y, w, h, out)
        except KeyError:
            raise HTTPException(404, "crop outside the image") from None
        return Response(data, media_type="image/jpeg", headers=_IMG_CACHE | {"X-Crop-Box": ",".join(map(str, box))})

    return app
