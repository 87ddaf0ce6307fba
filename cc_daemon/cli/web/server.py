"""The page's HTTP server (aiohttp): the page, its JSON and the downloads, GET only.

The status comes from the daemon's socket, read in a thread with a 1 s timeout
and shared by every client for half a second, so ten phones polling cost the
daemon two reads a second; the journal is read in a thread through
`JournalReader` (read-only). Nothing here can write to either, and an error in
a handler is that request's 500, never the daemon's concern.
"""

from __future__ import annotations

import asyncio
import time
from collections.abc import Awaitable, Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any

from aiohttp import web

from cc_daemon.cli.status.client import StatusUnavailable, read_status
from cc_daemon.cli.web import downloads, journaldata
from cc_daemon.cli.web.auth import BasicAuth
from cc_daemon.export import OptionalDependencyError
from cc_daemon.store import StoreError

STATUS_TIMEOUT_S = 1.0
STATUS_SHARED_S = 0.5  # one socket read serves every client asking within this
# Journal reads and downloads at once, at most: ten phones fetching NetCDF must not
# take the Pi's cores (or its memory) from the daemon. The others wait their turn.
JOURNAL_AT_ONCE = 2
# What every open page asks on a timer is read once for all of them within this:
# where the service's user cannot write beside the journal, each read copies it.
JOURNAL_SHARED_S = {"latest": 4.5, "surveys": 10.0}
ASSETS = {
    "/": ("index.html", "text/html; charset=utf-8"),
    "/static/page.css": ("page.css", "text/css; charset=utf-8"),
    "/static/page.js": ("page.js", "text/javascript; charset=utf-8"),
}
# Everything the page needs comes from here: no CDN, no inline script.
_HEADERS = {
    "Content-Security-Policy": "default-src 'self'; img-src 'self' data:; frame-ancestors 'none'",
    "X-Content-Type-Options": "nosniff",
    "Referrer-Policy": "no-referrer",
    "Cache-Control": "no-store",
}

Handler = Callable[[web.Request], Awaitable[web.StreamResponse]]


@dataclass(frozen=True, slots=True)
class Sources:
    socket: Path  # the daemon's status socket; `also`: where else it may be, in order
    journal: Path
    password_hash: str | None = None
    also: tuple[Path, ...] = ()


def asset(name: str) -> bytes:
    return resources.files("cc_daemon.cli.web").joinpath("static", name).read_bytes()


class StatusCache:
    """The last status document (or why there is none), shared for STATUS_SHARED_S."""

    def __init__(self, socket: Path, also: tuple[Path, ...] = ()) -> None:
        # The daemon may start after the page: each read asks the first path there.
        self._paths = (socket, *also)
        self._at = -1e9
        self._doc: dict[str, Any] = {}
        self._lock = asyncio.Lock()
        # Its own thread: journal reads filling the default pool never delay the status.
        self._thread = ThreadPoolExecutor(1, thread_name_prefix="status-read")

    async def get(self) -> dict[str, Any]:
        async with self._lock:
            if time.monotonic() - self._at >= STATUS_SHARED_S:
                loop = asyncio.get_running_loop()
                self._doc = await loop.run_in_executor(self._thread, self._read)
                self._at = time.monotonic()
            return self._doc

    def close(self) -> None:
        self._thread.shutdown(wait=False)

    def _read(self) -> dict[str, Any]:
        path = next((p for p in self._paths if p.exists()), self._paths[0])
        try:
            doc = read_status(path, timeout_s=STATUS_TIMEOUT_S)
        except StatusUnavailable as exc:
            return {"reachable": False, "reason": str(exc), "read_at": time.time()}
        return {**doc, "reachable": True, "read_at": time.time()}


def _json_error(status: int, message: str) -> web.Response:
    return web.json_response({"error": message}, status=status)


def _int(request: web.Request, name: str) -> int:
    try:
        return int(request.match_info[name])
    except ValueError:
        raise web.HTTPNotFound() from None


class Shared:
    """One journal answer per name shared by every client for JOURNAL_SHARED_S."""

    def __init__(self) -> None:
        self._kept: dict[str, tuple[float, Any]] = {}
        self._locks: dict[str, asyncio.Lock] = {}

    async def get(self, name: str, produce: Callable[[], Awaitable[Any]]) -> Any:
        async with self._locks.setdefault(name, asyncio.Lock()):
            kept = self._kept.get(name)
            if kept is None or time.monotonic() - kept[0] >= JOURNAL_SHARED_S[name]:
                kept = (time.monotonic(), await produce())
                self._kept[name] = kept
            return kept[1]


async def _journal(
    gate: asyncio.Semaphore,
    call: Callable[..., Any],
    *args: Any,
    shared: tuple[Shared, str] | None = None,
) -> web.Response:
    async def produce() -> Any:
        async with gate:
            return await asyncio.to_thread(call, *args)

    try:
        body = await (shared[0].get(shared[1], produce) if shared else produce())
    except journaldata.NotFound as exc:
        return _json_error(404, str(exc))
    except StoreError as exc:
        return _json_error(503, str(exc))
    return web.json_response(body)


def build_app(sources: Sources) -> web.Application:
    auth = BasicAuth(sources.password_hash) if sources.password_hash else None
    status = StatusCache(sources.socket, sources.also)
    gate = asyncio.Semaphore(JOURNAL_AT_ONCE)
    shared = Shared()
    pages = {path: (asset(name), kind) for path, (name, kind) in ASSETS.items()}

    @web.middleware
    async def guard(request: web.Request, handler: Handler) -> web.StreamResponse:
        if auth is not None and not auth.allows(request.headers.get("Authorization")):
            response: web.StreamResponse = web.Response(
                status=401,
                text="the field page needs its password\n",
                headers={"WWW-Authenticate": 'Basic realm="cc-daemon", charset="UTF-8"'},
            )
        else:
            try:
                response = await handler(request)
            except web.HTTPException as exc:  # 404, 405: raised, with our headers
                exc.headers.update(_HEADERS)
                raise
        response.headers.update(_HEADERS)
        return response

    async def page(request: web.Request) -> web.Response:
        body, kind = pages[request.path]
        return web.Response(body=body, headers={"Content-Type": kind})

    async def api_status(request: web.Request) -> web.Response:
        return web.json_response(await status.get())

    async def api_surveys(request: web.Request) -> web.Response:
        return await _journal(
            gate, journaldata.surveys, sources.journal, shared=(shared, "surveys")
        )

    async def api_casts(request: web.Request) -> web.Response:
        return await _journal(gate, journaldata.survey_casts, sources.journal, _int(request, "n"))

    async def api_profile(request: web.Request) -> web.Response:
        return await _journal(gate, journaldata.cast_profile, sources.journal, _int(request, "n"))

    async def api_latest(request: web.Request) -> web.Response:
        return await _journal(
            gate, journaldata.latest, sources.journal, time.time(), shared=(shared, "latest")
        )

    async def api_events(request: web.Request) -> web.Response:
        text = request.query.get("survey")
        if text is not None and not text.isdigit():
            return _json_error(400, f"survey={text!r}: a survey's number, e.g. survey=3")
        survey = None if text is None else int(text)
        return await _journal(gate, journaldata.events, sources.journal, survey)

    async def download(request: web.Request) -> web.Response:
        n, fmt = _int(request, "n"), request.match_info["fmt"]
        try:
            async with gate:
                body = await asyncio.to_thread(downloads.survey_file, sources.journal, n, fmt)
        except journaldata.NotFound as exc:
            return _json_error(404, str(exc))
        except OptionalDependencyError as exc:
            return _json_error(503, f"{exc} (on the Pi: pip install 'cc-daemon[netcdf]')")
        except StoreError as exc:
            return _json_error(503, str(exc))
        except ValueError as exc:  # NetCDF of a survey without a cast
            return _json_error(404, f"survey {n}: {exc}")
        return web.Response(
            body=body,
            headers={
                "Content-Type": downloads.FORMATS[fmt],
                "Content-Disposition": f'attachment; filename="survey-{n}.{fmt}"',
            },
        )

    async def stop_status(app: web.Application) -> None:
        status.close()

    app = web.Application(middlewares=[guard])
    app.on_cleanup.append(stop_status)
    for path in pages:
        app.router.add_get(path, page)
    app.router.add_get("/api/status", api_status)
    app.router.add_get("/api/surveys", api_surveys)
    app.router.add_get("/api/surveys/{n}/casts", api_casts)
    app.router.add_get("/api/casts/{n}/profile", api_profile)
    app.router.add_get("/api/events", api_events)
    app.router.add_get("/api/latest", api_latest)
    app.router.add_get(r"/download/survey/{n}.{fmt:csv|geojson|nc}", download)
    return app


def split_listen(listen: str) -> tuple[str, int]:
    host, _, port = listen.rpartition(":")
    return host.strip("[]"), int(port)


async def serve(sources: Sources, listen: str, *, ready: Callable[[str], None]) -> None:
    """Serve until cancelled. OSError if the address cannot be bound."""
    runner = web.AppRunner(
        build_app(sources), access_log=None, handle_signals=False, shutdown_timeout=1.0
    )
    await runner.setup()
    try:
        host, port = split_listen(listen)
        site = web.TCPSite(runner, host, port)
        await site.start()
        bound = runner.addresses[0]  # the real port when asked for port 0
        ready(f"{host if ':' not in host else f'[{host}]'}:{bound[1]}")
        await asyncio.Event().wait()
    finally:
        await runner.cleanup()
