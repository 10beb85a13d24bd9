"""The labeling web app: a FastAPI server for the static page in ``static/``.

Security model
--------------
- **Files.** Only images the campaign index lists are served, by opaque id; their paths were
  resolved (symlinks followed) and checked to lie inside the campaign. The page's own files come
  from the package's ``static/`` folder (Starlette's ``StaticFiles``: no traversal, no symlinks
  out). Anything else is 404.
- **Writes** go to the label store only, through :class:`PutBody` / :class:`UndoBody`
  (pydantic, extra fields refused, values checked per kind), bodies over
  :data:`MAX_BODY_BYTES` refused with 413.
- **Cross-site requests.** Every state-changing request must carry the header
  ``X-Solidkit: 1`` (a cross-site form or image cannot; a cross-site script would need a CORS
  preflight, which this server never grants), must not come from another origin (``Origin``,
  ``Sec-Fetch-Site``), and the ``Host`` header must name this server (DNS rebinding).
- **Token mode** (any bind address other than loopback): the token is typed into the page once
  and exchanged (``POST /api/session``, in the body, never in a URL) for an ``HttpOnly``,
  ``SameSite=Strict`` session cookie; scripts may send ``Authorization: Bearer TOKEN``. Every
  ``/api`` route except the session exchange answers 401 without it.
"""

from __future__ import annotations

import base64
import hashlib
import hmac
import re
import secrets
from pathlib import Path
from typing import Any, Literal, cast

from fastapi import Depends, FastAPI, HTTPException, Query, Request
from fastapi.responses import FileResponse, JSONResponse, Response
from fastapi.staticfiles import StaticFiles
from pydantic import BaseModel, ConfigDict, Field
from starlette.middleware.trustedhost import TrustedHostMiddleware

from solidkit.errors import InputError
from solidkit.labeling.images import PREVIEW_WIDTH, ImageService, tile_grid
from solidkit.labeling.review import THRESHOLDS, UNITS, disagreement_flag, review_all, review_item
from solidkit.labeling.store import LabelConflict, LabelStore, validate_value
from solidkit.labeling.tasks import TASKS, CampaignIndex

__all__ = ["create_app", "MAX_BODY_BYTES", "LOOPBACK_HOSTS", "PutBody", "UndoBody"]

STATIC = Path(__file__).parent / "static"
MAX_BODY_BYTES = 16 * 1024
LOOPBACK_HOSTS = ("127.0.0.1", "localhost", "::1", "[::1]")
SESSION_COOKIE = "solidkit_session"
_IMG_ID = r"^img-[0-9a-f]{16}$"
_WEB_FIELDS = {
    "sun": {"found", "azimuth_deg", "elevation_deg", "uncertainty_deg"},
    "probe_pixel": {"x", "y"},
    "heading": {"yaw_deg"},
}
_UNSAFE = {"POST", "PUT", "PATCH", "DELETE"}


class _Body(BaseModel):
    model_config = ConfigDict(extra="forbid")


class PutBody(_Body):
    """A label edit from the page."""

    kind: Literal["sun", "probe_pixel", "heading"]
    key: str = Field(max_length=200)
    value: dict[str, bool | float | int | None]
    expected_version: int = Field(ge=0, description="the version the edit was based on (0: no label seen)")
    annotator: str = Field(min_length=1, max_length=64)
    source: Literal["annotator", "reviewed"] = "annotator"
    flags: list[str] = Field(default_factory=list, max_length=8)


class UndoBody(_Body):
    kind: Literal["sun", "probe_pixel", "heading"]
    key: str = Field(max_length=200)
    expected_version: int = Field(ge=0)
    annotator: str = Field(min_length=1, max_length=64)


class SessionBody(_Body):
    token: str = Field(max_length=256)


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
) -> FastAPI:
    """Build the app for one campaign.

    Parameters
    ----------
    campaign_dir : path
        The campaign (manifest, products; the label store is created in ``labels/``).
    alignment : dict, optional
        ``align/alignment.json`` as a dict (automatic proposals), or None.
    token : str, optional
        Require this token (token mode). None: no authentication (loopback only; the CLI
        enforces that).
    allowed_hosts : list of str, optional
        Host names the ``Host`` header may carry (default: the loopback names).
    """
    index = CampaignIndex(campaign_dir, alignment)
    store = LabelStore(index.root)
    images = ImageService()
    sessions: set[str] = set()
    index_html = (STATIC / "index.html").read_text(encoding="utf-8")
    csp = _csp(index_html)

    app = FastAPI(title="solidkit labeling", docs_url=None, redoc_url=None, openapi_url=None)
    app.state.index, app.state.store, app.state.images = index, store, images

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

    def auth(request: Request) -> None:
        if token is None:
            return
        sid = request.cookies.get(SESSION_COOKIE)
        if sid and any(hmac.compare_digest(sid, s) for s in sessions):
            return
        bearer = request.headers.get("authorization", "")
        if bearer.startswith("Bearer ") and hmac.compare_digest(bearer[7:].encode(), token.encode()):
            return
        raise HTTPException(401, "token required: open the page and enter the token printed by `solidkit label serve`")

    # -- page --------------------------------------------------------------------------------
    @app.get("/", include_in_schema=False)
    def page() -> FileResponse:
        return FileResponse(STATIC / "index.html", headers={"Cache-Control": "no-cache"})

    app.mount("/static", StaticFiles(directory=STATIC, follow_symlink=False), name="static")

    # -- session -----------------------------------------------------------------------------
    @app.get("/api/session")
    def session_state(request: Request) -> dict:
        try:
            auth(request)
            ok = True
        except HTTPException:
            ok = False
        return {"token_required": token is not None, "authenticated": ok}

    @app.post("/api/session")
    def login(body: SessionBody) -> Response:
        if token is None:
            return JSONResponse({"authenticated": True})
        if not hmac.compare_digest(body.token.encode(), token.encode()):
            raise HTTPException(401, "wrong token")
        sid = secrets.token_urlsafe(32)
        sessions.add(sid)
        resp = JSONResponse({"authenticated": True})
        resp.set_cookie(SESSION_COOKIE, sid, httponly=True, samesite="strict", path="/")
        return resp

    # -- campaign and queues -----------------------------------------------------------------
    def progress() -> dict:
        out = {}
        reviews = review_all(index, store)
        for kind in TASKS:
            rs = [r for r in reviews if r.kind == kind]
            out[kind] = {s: sum(r.status == s for r in rs) for s in ("done", "flagged", "left")} | {"total": len(rs)}
        out["review"] = {"open": sum(bool(r.flags) and r.status != "done" or r.open_disagreement for r in reviews)}
        return out

    @app.get("/api/campaign", dependencies=[Depends(auth)])
    def campaign() -> dict:
        return {
            "name": index.root.name,
            "scenes": [s.id for s in index.manifest.scenes],
            "progress": progress(),
            "problems": index.problems,
            "thresholds": {k: {"value": v, "unit": UNITS[k]} for k, v in THRESHOLDS.items()},
            "has_alignment": bool(index.alignment),
        }

    @app.get("/api/queue/{kind}", dependencies=[Depends(auth)])
    def queue(kind: Literal["sun", "probe_pixel", "heading", "review"]) -> dict:
        if kind == "review":
            rows = [r for r in review_all(index, store) if r.flags or r.open_disagreement or r.opinions]
            order = {"flagged": 0, "left": 1, "done": 2}
            # biggest first, in units of each kind's threshold (degrees and pixels do not compare)
            rows.sort(
                key=lambda r: (
                    not r.open_disagreement,
                    order[r.status],
                    -(r.disagreement or r.vs_auto or 0.0) / THRESHOLDS[r.kind],
                )
            )
            items = [r.as_dict() | {"title": index.items[r.kind][r.key].title} for r in rows]
        else:
            items = [
                {
                    "kind": kind,
                    "key": r.key,
                    "title": index.items[kind][r.key].title,
                    "status": r.status,
                    "flags": r.flags,
                }
                for r in review_all(index, store, (kind,))
            ]
        return {"kind": kind, "items": items, "progress": progress()}

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

    @app.get("/api/item", dependencies=[Depends(auth)])
    def item(kind: Literal["sun", "probe_pixel", "heading"], key: str = Query(max_length=200)) -> dict:
        it = _item(kind, key)
        label = store.get(kind, key)
        history = store.history(kind, key)
        view, proposal = dict(it.view), it.proposal
        if proposal is None:  # no alignment.json: align's auto label in the store (`solidkit label sun`)
            auto = next((c for c in reversed(history) if c.source == "auto" and c.value), None)
            if auto is not None:
                auto_value = cast("dict[str, Any]", auto.value)  # the search kept a change with a value
                proposal = {k: v for k, v in auto_value.items() if k in _WEB_FIELDS[kind]}
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
                    lab = store.get(kind, other.key)
                    siblings[other.probe] = (lab.value if lab else None) or other.proposal
        return {
            "kind": kind, "key": key, "title": it.title, "scene": it.scene, "probe": it.probe, "view": view,
            "proposal": proposal, "flags": it.flags, "siblings": siblings,
            "label": label.model_dump(mode="json") if label else None, "version": store.version(kind, key),
            "review": review_item(it, label, history).as_dict(),
            "history": [c.model_dump(mode="json") for c in history[-30:]],
        }  # fmt: skip

    # -- writes ------------------------------------------------------------------------------
    def _conflict(exc: LabelConflict) -> JSONResponse:
        cur = exc.current.model_dump(mode="json") if exc.current else None
        return JSONResponse({"detail": str(exc), "current": cur, "version": exc.current_version}, status_code=409)

    @app.put("/api/label", dependencies=[Depends(auth)])
    def put_label(body: PutBody) -> Any:
        _item(body.kind, body.key)
        extra = set(body.value) - _WEB_FIELDS[body.kind]
        if extra:
            raise HTTPException(422, f"{body.kind}: unknown value fields {sorted(extra)}")
        flags = list(body.flags)
        if body.source == "annotator":  # a second opinion far from the first is flagged for review
            try:
                value = validate_value(body.kind, body.key, body.value)
            except InputError as exc:
                raise HTTPException(422, str(exc)) from None
            flag = disagreement_flag(body.kind, body.annotator, value, store.history(body.kind, body.key))
            flags += [flag] if flag else []
        try:
            lab = store.put(body.kind, body.key, body.value, source=body.source, annotator=body.annotator,
                            expected_version=body.expected_version, flags=flags)  # fmt: skip
        except LabelConflict as exc:
            return _conflict(exc)
        except InputError as exc:
            raise HTTPException(422, str(exc)) from None
        return {"label": lab.model_dump(mode="json"), "version": lab.version}

    @app.post("/api/undo", dependencies=[Depends(auth)])
    def undo(body: UndoBody) -> Any:
        _item(body.kind, body.key)
        try:
            lab = store.undo(body.kind, body.key, body.annotator, expected_version=body.expected_version)
        except LabelConflict as exc:
            return _conflict(exc)
        except InputError as exc:
            raise HTTPException(422, str(exc)) from None
        return {"label": lab.model_dump(mode="json") if lab else None, "version": store.version(body.kind, body.key)}

    @app.get("/api/export", dependencies=[Depends(auth)])
    def export() -> dict:
        return store.export()

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
