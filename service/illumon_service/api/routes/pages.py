"""The operator status page: ``GET /`` (every visible camera) and ``GET /cameras/{id}`` (one camera's history).

Server-rendered HTML (Jinja2 templates in ``illumon_service/templates``), one local stylesheet
(``illumon_service/static``) and inline SVG charts drawn in Python (:mod:`illumon_service.charts`): no JavaScript, no
build step, nothing fetched from elsewhere.

Authentication is that of the JSON API. ``Authorization: Bearer <token>`` works as there; a browser logs in at
``/login`` with the admin token or a camera token and gets an HTTP-only, ``SameSite=Strict`` cookie (``Secure`` when the
page is served over HTTPS) holding a random session id, not the token (:mod:`illumon_service.logins`: the server keeps
the id's SHA-256, the token's hash and an expiry; logout deletes it). The admin sees every camera; a camera token sees
only its own camera, and another camera's page answers 404 as an unknown one would. Without a valid token a page
redirects to the login form. Login and logout forms sent from another site (by their ``Origin``) are refused.
"""

from __future__ import annotations

from datetime import datetime
from pathlib import Path
from urllib.parse import quote, urlsplit

from fastapi import APIRouter, FastAPI, Form, HTTPException, Query, Request
from fastapi.responses import HTMLResponse, RedirectResponse, Response
from fastapi.staticfiles import StaticFiles
from fastapi.templating import Jinja2Templates
from markupsafe import Markup
from sqlalchemy.orm import Session
from starlette.concurrency import run_in_threadpool

from ... import crud
from ...charts import Series, time_chart
from ...deps import Principal, SessionDep, principal_from_token, visible_camera
from ...estimation import camera_primaries
from ...logins import MAX_AGE as LOGIN_MAX_AGE
from ...logins import create_login, end_login, principal_from_login
from ...manage import proposals_for, save_regions_and_measure
from ...proposals import MAX_FRAMES, preview_jpeg
from ...registration import parse_view, view_thumbnails
from ...status import NON_DAYLIGHT_DUV, REASON_WORDS, camera_status, chart_history, fleet_status
from ...storage import Camera, as_utc
from ..forms import regions_from_form
from ..schemas import RegionsIn

__all__ = ["router", "install", "COOKIE"]

PACKAGE = Path(__file__).resolve().parents[2]
TEMPLATES = Jinja2Templates(directory=str(PACKAGE / "templates"))
STATIC = PACKAGE / "static"
COOKIE = "illumon_session"
"""Name of the login cookie (a random session id, :mod:`illumon_service.logins`; never the token)."""
COOKIE_MAX_AGE = int(LOGIN_MAX_AGE.total_seconds())
HEADERS = {
    "Cache-Control": "no-store",
    "Content-Security-Policy": "default-src 'none'; style-src 'self'; img-src 'self' data:; form-action 'self'; "
                               "frame-ancestors 'none'; base-uri 'none'",
    "X-Frame-Options": "DENY",
    "X-Content-Type-Options": "nosniff",
    "Referrer-Policy": "same-origin",  # "no-referrer" would make browsers send "Origin: null" with the login form
}

router = APIRouter(tags=["pages"], include_in_schema=False)


def _fmt_time(value: datetime | str | None) -> str:
    """``YYYY-MM-DD HH:MM UTC`` (or an em dash)."""
    if value is None:
        return "—"
    if isinstance(value, str):
        value = datetime.fromisoformat(value)
    return value.strftime("%Y-%m-%d %H:%M UTC")


TEMPLATES.env.filters["utc"] = _fmt_time


def _principal(request: Request, session: Session) -> Principal | None:
    """Caller from ``Authorization: Bearer`` or, failing that, the login cookie."""
    scheme, _, token = request.headers.get("authorization", "").partition(" ")
    if scheme.lower() == "bearer" and token.strip():
        return principal_from_token(request, session, token)
    return principal_from_login(request, session, request.cookies.get(COOKIE, ""))


def _safe_next(target: str | None) -> str:
    """A local path to go to after login (never another site)."""
    if not target or not target.startswith("/") or target.startswith("//") or "\\" in target:
        return "/"
    return target


def _same_origin(request: Request) -> bool:
    """False when a browser says the form was sent from another site: ``Origin`` names neither ``Host`` nor, behind a
    reverse proxy, ``X-Forwarded-Host`` (``Origin: null`` is refused too; no ``Origin`` at all is not a browser's form)."""
    origin = request.headers.get("origin")
    if not origin or origin == "null":
        return origin is None
    hosts = {request.headers.get("host", "")} | {h.strip() for h in request.headers.get("x-forwarded-host", "").split(",")}
    return urlsplit(origin).netloc in hosts - {""}


def _to_login(request: Request) -> RedirectResponse:
    path = request.url.path + (f"?{request.url.query}" if request.url.query else "")
    resp = RedirectResponse(f"/login?next={quote(path, safe='/')}", status_code=303)
    if request.cookies.get(COOKIE):
        resp.delete_cookie(COOKIE, path="/")
    return resp


def _render(request: Request, name: str, context: dict, status_code: int = 200) -> HTMLResponse:
    resp = TEMPLATES.TemplateResponse(request, name, context, status_code=status_code)
    resp.headers.update(HEADERS)
    return resp


@router.get("/login", response_class=HTMLResponse)
def login_form(request: Request, next_: str = Query("/", alias="next")) -> HTMLResponse:
    """The login form (admin token or camera token)."""
    return _render(request, "login.html", {"next": _safe_next(next_), "error": None, "principal": None})


@router.post("/login")
def login(request: Request, session: SessionDep, token: str = Form(""),
          next_: str = Form("/", alias="next")) -> Response:
    """Check the token; on success set the HTTP-only login cookie and go to ``next``. Forms from other sites: 403."""
    if not _same_origin(request):
        return _render(request, "login.html", {"next": "/", "error": "Log in from this site's own form.", "principal": None},
                       status_code=403)
    principal = principal_from_token(request, session, token)
    if principal is None:
        return _render(request, "login.html", {"next": _safe_next(next_), "error": "Unknown token.", "principal": None},
                       status_code=401)
    resp = RedirectResponse(_safe_next(next_), status_code=303)
    resp.set_cookie(COOKIE, create_login(session, token), max_age=COOKIE_MAX_AGE, path="/", httponly=True, samesite="strict",
                    secure=request.url.scheme == "https")
    return resp


@router.post("/logout")
def logout(request: Request, session: SessionDep) -> Response:
    """End the login session and forget its cookie (forms from other sites: 403)."""
    if not _same_origin(request):
        return Response("cross-site logout refused", status_code=403, headers=HEADERS)
    end_login(session, request.cookies.get(COOKIE, ""))
    resp = RedirectResponse("/login", status_code=303)
    resp.delete_cookie(COOKIE, path="/")
    return resp


@router.get("/", response_class=HTMLResponse)
def index(request: Request, session: SessionDep) -> Response:
    """Every camera the caller may see: latest CCT, Duv, gains, confidence, last frame and alerts."""
    principal = _principal(request, session)
    if principal is None:
        return _to_login(request)
    rows = fleet_status(session, principal, request.app.state.settings)
    return _render(request, "index.html", {"rows": rows, "principal": principal})


def _charts(history: list[dict]) -> dict[str, Markup]:
    """CCT with its interval, Duv with its interval and the r/b gains (with intervals) over time, as SVG.

    Each chart comes twice, wide (desktop) and compact (phone: a narrower viewBox keeps the text legible); the
    stylesheet shows one of them.
    """
    times = [datetime.fromisoformat(e["taken_at"]) for e in history]

    def iv(key: str, index: int | None = None) -> list[float | None]:
        out: list[float | None] = []
        for e in history:
            v = (e.get("intervals") or {}).get(key)
            out.append(v[index] if (v is not None and index is not None) else v)
        return out

    specs = {
        "cct": ([Series("CCT", times, [e["cct_k"] for e in history], iv("cct_lo"), iv("cct_hi"))],
                {"title": "Correlated colour temperature", "unit": "K"}),
        "duv": ([Series("Duv", times, [e["duv"] for e in history], iv("duv_lo"), iv("duv_hi"), css="series-1",
                        band_css="band-1")],
                {"title": "Duv (distance from the Planckian locus)", "refs": (0.0, NON_DAYLIGHT_DUV, -NON_DAYLIGHT_DUV)}),
        "gains": ([Series("R gain", times, [e["gains_rgb"][0] for e in history], iv("gain_lo", 0), iv("gain_hi", 0),
                          css="series-r", band_css="band-r"),
                   Series("B gain", times, [e["gains_rgb"][2] for e in history], iv("gain_lo", 2), iv("gain_hi", 2),
                          css="series-b", band_css="band-b")],
                  {"title": "White-balance gains (G = 1)", "refs": (1.0,)}),
    }
    out = {}
    for key, (series, kw) in specs.items():
        wide = time_chart(series, chart_id=f"chart-{key}", css_class="chart wide", **kw)
        compact = time_chart(series, chart_id=f"chart-{key}-compact", css_class="chart compact", width=400, height=250, **kw)
        out[key] = Markup(wide + compact)
    return out


@router.get("/cameras/{camera_id}", response_class=HTMLResponse)
def camera_page(camera_id: int, request: Request, session: SessionDep, limit: int = 2000) -> Response:
    """One camera: its status, CCT and Duv over time with their intervals, the gains over time, recent estimates."""
    principal = _principal(request, session)
    if principal is None:
        return _to_login(request)
    cam = visible_camera(session, principal, camera_id)
    if cam is None:
        return _render(request, "not_found.html", {"camera_id": camera_id, "principal": principal}, status_code=404)
    status = camera_status(session, cam, request.app.state.settings)
    history = chart_history(session, camera_id, limit=max(1, min(limit, 20000)))
    primaries = camera_primaries(cam.response, cam.sensitivities is not None)
    return _render(request, "camera.html", {"row": status, "charts": _charts(history.points), "recent": history.recent,
                                            "count": history.count, "stride": history.stride, "principal": principal,
                                            "output": PRIMARIES_WORDS[primaries], "reason_words": REASON_WORDS})


PRIMARIES_WORDS = {"camera": "sensor RGB (primaries: camera)", "srgb": "rendered, sRGB primaries (primaries: srgb)"}


KEEP_FRACTION = 0.5
"""On the regions page of a camera without regions, proposals scoring at least this fraction of the best one are
ticked (scores are comparable within a scene, not across scenes: the day's light makes every surface drift more or
less)."""


def ticked_score(proposals: list[dict]) -> float:
    """The score from which proposals are ticked by default (:data:`KEEP_FRACTION` of the best)."""
    return KEEP_FRACTION * max((p["score"] for p in proposals), default=0.0)


def _view_arg(view: str | None) -> str | None:
    try:
        return parse_view(view)
    except ValueError:
        return None


def _regions_context(session: Session, cam: Camera, view: str | None, data_dir: Path) -> dict:
    """What the regions page shows: the view's regions, the latest frame's size and time, and proposals."""
    thumbs, frames = view_thumbnails(session, cam, view, data_dir, MAX_FRAMES)
    ctx: dict = {"cam": cam, "view": view, "regions": crud.view_regions(session, cam, view), "proposals": [],
                 "frames_used": 0, "proposal_error": None, "size": None, "latest_at": None, "view_changed": False,
                 "error": None, "saved": False, "keep_score": 0.0}
    if frames:
        ctx["size"] = (frames[0].width, frames[0].height)
        ctx["latest_at"] = as_utc(frames[0].taken_at)
    latest = crud.latest_frame(session, cam.id, view)
    ctx["view_changed"] = bool(latest is not None and (latest.registration or {}).get("state") == "view_change")
    try:
        out = proposals_for(session, cam, view, 12, data_dir)
        ctx["proposals"], ctx["frames_used"] = out["proposals"], out["frames_used"]
        ctx["keep_score"] = round(ticked_score(out["proposals"]), 2)
    except HTTPException as exc:
        ctx["proposal_error"] = f"No proposals yet: {exc.detail}."
    return ctx


def _page_camera(request: Request, session: Session, camera_id: int) -> tuple[Principal | None, Camera | None]:
    principal = _principal(request, session)
    if principal is None:
        return None, None
    return principal, visible_camera(session, principal, camera_id)


@router.get("/cameras/{camera_id}/regions", response_class=HTMLResponse)
def regions_page(camera_id: int, request: Request, session: SessionDep, view: str | None = None,
                 saved: int = 0) -> Response:
    """The latest frame with the view's regions and the proposals drawn on it, and a form to keep, drop, rename
    or add regions (saved like ``PUT /v1/cameras/{id}/regions``)."""
    principal, cam = _page_camera(request, session, camera_id)
    if principal is None:
        return _to_login(request)
    if cam is None:
        return _render(request, "not_found.html", {"camera_id": camera_id, "principal": principal}, status_code=404)
    ctx = _regions_context(session, cam, _view_arg(view), request.app.state.settings.data_dir)
    ctx.update({"principal": principal, "saved": bool(saved)})
    return _render(request, "regions.html", ctx)


@router.get("/cameras/{camera_id}/latest.jpg")
def latest_frame_jpeg(camera_id: int, request: Request, session: SessionDep, view: str | None = None) -> Response:
    """The view's latest stored frame, downscaled and moved into its reference frame, as a JPEG."""
    principal, cam = _page_camera(request, session, camera_id)
    if cam is None:
        return Response(status_code=401 if principal is None else 404, headers=HEADERS)
    thumbs, _ = view_thumbnails(session, cam, _view_arg(view), request.app.state.settings.data_dir, 1)
    if not thumbs:
        return Response(status_code=404, headers=HEADERS)
    return Response(preview_jpeg(thumbs[0]), media_type="image/jpeg", headers=HEADERS)


@router.post("/cameras/{camera_id}/regions", response_class=HTMLResponse)
async def save_regions_form(camera_id: int, request: Request, session: SessionDep, view: str | None = None) -> Response:
    """Save the regions form through the code of ``PUT /v1/cameras/{id}/regions``; forms from other sites: 403."""
    if not _same_origin(request):
        return Response("cross-site form refused", status_code=403, headers=HEADERS)
    form = {k: v for k, v in (await request.form()).items() if isinstance(v, str)}

    def work() -> Response:
        principal, cam = _page_camera(request, session, camera_id)
        if principal is None:
            return _to_login(request)
        if cam is None:
            return _render(request, "not_found.html", {"camera_id": camera_id, "principal": principal}, status_code=404)
        v = _view_arg(view)
        error = None
        try:
            body = RegionsIn(regions=regions_from_form(form))
            save_regions_and_measure(session, cam, [r.model_dump() for r in body.regions], v,
                                     request.app.state.settings, form.get("reference_latest") == "1")
        except ValueError as exc:  # a malformed number, or pydantic's ValidationError
            errs = getattr(exc, "errors", None)
            error = "; ".join(f"{'.'.join(map(str, e['loc']))}: {e['msg']}" for e in errs()) if errs else str(exc)
        except HTTPException as exc:
            error = str(exc.detail)
        if error is not None:
            ctx = _regions_context(session, cam, v, request.app.state.settings.data_dir)
            ctx.update({"principal": principal, "error": f"Not saved: {error}"})
            return _render(request, "regions.html", ctx, status_code=422)
        q = f"?view={quote(v)}&saved=1" if v else "?saved=1"
        return RedirectResponse(f"/cameras/{camera_id}/regions{q}", status_code=303)

    return await run_in_threadpool(work)


def install(app: FastAPI) -> None:
    """Add the pages and their stylesheet (``/static``) to ``app``."""
    app.include_router(router)
    app.mount("/static", StaticFiles(directory=str(STATIC)), name="static")
