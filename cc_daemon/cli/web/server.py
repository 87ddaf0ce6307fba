"""The page's HTTP server (aiohttp): the page, its JSON and the downloads, GET only.

The status comes from the daemon's socket, read in a thread with a 1 s timeout
and shared by every client for half a second, so ten phones polling cost the
daemon two reads a second; the journal is read in a thread through
`JournalReader` (read-only), and a download is written on a thread of its own
and streamed (`downloads`, `pipe`). Nothing here can write to either, and an
error in a handler is that request's answer (`guard`), never the daemon's
concern. Which connections are held is `listener`'s business; what a request
must pass first, `guard`'s.
"""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import re
import time
from collections.abc import AsyncIterator, Awaitable, Callable
from concurrent.futures import ThreadPoolExecutor
from importlib import resources
from pathlib import Path
from typing import IO, TYPE_CHECKING, Any

import structlog
from aiohttp import web

from cc_daemon.cli.status.client import StatusUnavailable, read_status
from cc_daemon.cli.web import downloads, journaldata, science
from cc_daemon.cli.web.auth import BasicAuth
from cc_daemon.cli.web.guard import Refused, add_headers, default_names, middleware, number
from cc_daemon.cli.web.listener import Listener, open_sockets
from cc_daemon.cli.web.pipe import CHUNK, Pipe
from cc_daemon.cli.web.policy import Limits
from cc_daemon.export import OptionalDependencyError
from cc_daemon.store import StoreError

if TYPE_CHECKING:
    from cc_daemon.config.survey import SurveySettings

log = structlog.get_logger(__name__)

STATUS_TIMEOUT_S = 1.0
STATUS_SHARED_S = 0.5  # one socket read serves every client asking within this
# A status document deeper than this is not the daemon's (its sections are two
# levels deep): shown as unreadable, never serialised again or drawn.
STATUS_MAX_DEPTH = 32
# Journal reads at once, at most: ten phones must not take the Pi's cores (or
# its memory) from the daemon. The others wait their turn.
JOURNAL_AT_ONCE = 2
# Downloads at once, each on a thread of its own; apart from the journal reads,
# so a long download never holds up the page's tables.
DOWNLOADS_AT_ONCE = 2
# What every open page asks on a timer is read once for all of them within this:
# where the service's user cannot write beside the journal, each read copies it.
JOURNAL_SHARED_S = {"latest": 4.5, "surveys": 10.0}
# The science's files, by the names the commands give them (`science.PRODUCTS`).
PRODUCT_NAMES = "|".join(re.escape(name) for name in science.PRODUCTS)
ASSETS = {
    "/": ("index.html", "text/html; charset=utf-8"),
    "/static/page.css": ("page.css", "text/css; charset=utf-8"),
    "/static/page.js": ("page.js", "text/javascript; charset=utf-8"),
    "/static/words.js": ("words.js", "text/javascript; charset=utf-8"),
    "/static/draw.js": ("draw.js", "text/javascript; charset=utf-8"),
    "/static/today.js": ("today.js", "text/javascript; charset=utf-8"),
    "/static/dom.js": ("dom.js", "text/javascript; charset=utf-8"),
    "/static/science.js": ("science.js", "text/javascript; charset=utf-8"),
}


@dataclasses.dataclass(frozen=True, slots=True)
class Sources:
    socket: Path  # the daemon's status socket; `also`: where else it may be, in order
    journal: Path
    password_hash: str | None = None
    also: tuple[Path, ...] = ()
    hosts: frozenset[str] = frozenset({"localhost"})  # names answered (`guard.default_names`)
    survey: SurveySettings | None = None  # the map's `[survey]` keys (None: the defaults)


def asset(name: str) -> bytes:
    return resources.files("cc_daemon.cli.web").joinpath("static", name).read_bytes()


def deeper_than(doc: Any, limit: int) -> bool:
    """Whether `doc` nests more than `limit` levels (looked at without recursion)."""
    stack = [(doc, 1)]
    while stack:
        value, depth = stack.pop()
        if isinstance(value, dict | list):
            if depth > limit:
                return True
            items = value.values() if isinstance(value, dict) else value
            stack.extend((item, depth + 1) for item in items)
    return False


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
        except RecursionError:  # json's own limit: about 1,000 levels
            doc = None
        if doc is None or deeper_than(doc, STATUS_MAX_DEPTH):
            reason = (
                f"{path}: the answer is not a status document"
                f" (it nests deeper than {STATUS_MAX_DEPTH} levels)"
            )
            return {"reachable": False, "reason": reason, "read_at": time.time()}
        return {**doc, "reachable": True, "read_at": time.time()}


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
    finish: Callable[[Any], Any] | None = None,
) -> web.Response:
    async def produce() -> Any:
        async with gate:
            return await asyncio.to_thread(call, *args)

    try:
        body = await (shared[0].get(shared[1], produce) if shared else produce())
    except journaldata.NotFound as exc:
        raise Refused(404, str(exc)) from None
    except StoreError as exc:
        raise Refused(503, str(exc)) from None
    return web.json_response(body if finish is None else finish(body))


async def _first(chunks: AsyncIterator[bytes], survey: int) -> bytes | None:
    """The download's first chunk (None: an empty file), or why there is none."""
    try:
        return await anext(chunks, None)
    except journaldata.NotFound as exc:
        raise Refused(404, str(exc)) from None
    except OptionalDependencyError as exc:
        raise Refused(503, f"{exc} (on the Pi: pip install 'cc-daemon[netcdf]')") from None
    except StoreError as exc:
        raise Refused(503, str(exc)) from None
    except ValueError as exc:  # NetCDF of a survey without a cast
        raise Refused(404, f"survey {survey}: {exc}") from None


async def _send(
    request: web.Request,
    response: web.StreamResponse,
    first: bytes | None,
    chunks: AsyncIterator[bytes],
    stall_s: float,
) -> None:
    """Send the download; cut the connection if its client stalls or the file fails
    half-way (the client then sees a broken download, never a truncated file)."""
    try:
        if first is not None:
            # asyncio.timeout, not wait_for: on Python 3.11 wait_for drops a cancel (the
            # page stopping) that meets a write completing (cc_daemon/drivers/sonde/reader.py).
            async with asyncio.timeout(stall_s):
                await response.write(first)
            async for chunk in chunks:
                async with asyncio.timeout(stall_s):
                    await response.write(chunk)
        await response.write_eof()
        return
    except ConnectionError:
        return  # the client left
    except TimeoutError:
        log.warning("a download's client stopped reading: the download was dropped")
    except Exception as exc:
        log.error("a download failed after it began", error=type(exc).__name__, exc_info=exc)
    if request.transport is not None:
        request.transport.abort()


def build_app(sources: Sources, limits: Limits | None = None) -> web.Application:
    limits = limits or Limits()
    auth = BasicAuth(sources.password_hash, limits) if sources.password_hash else None
    status = StatusCache(sources.socket, sources.also)
    gate = asyncio.Semaphore(JOURNAL_AT_ONCE)
    download_turns = asyncio.Semaphore(DOWNLOADS_AT_ONCE)
    download_threads = ThreadPoolExecutor(DOWNLOADS_AT_ONCE, thread_name_prefix="download")
    shared = Shared()
    made = science.Science(sources.journal, sources.survey)
    pages = {path: (asset(name), kind) for path, (name, kind) in ASSETS.items()}

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
        n = number(request.match_info["n"], "survey")
        return await _journal(gate, journaldata.survey_casts, sources.journal, n)

    async def api_profile(request: web.Request) -> web.Response:
        n = number(request.match_info["n"], "cast")
        return await _journal(gate, journaldata.cast_profile, sources.journal, n)

    async def api_latest(request: web.Request) -> web.Response:
        # Shared for a few seconds; each reading's age is as of this answer.
        return await _journal(
            gate, journaldata.latest, sources.journal, time.time(), shared=(shared, "latest"),
            finish=lambda doc: journaldata.aged(doc, time.time()),
        )  # fmt: skip

    async def api_events(request: web.Request) -> web.Response:
        text = request.query.get("survey")
        survey = None if text is None else number(text, "survey")
        return await _journal(gate, journaldata.events, sources.journal, survey)

    async def download(request: web.Request) -> web.StreamResponse:
        n, fmt = number(request.match_info["n"], "survey"), request.match_info["fmt"]
        async with download_turns:
            pipe = Pipe(asyncio.get_running_loop())
            chunks = pipe.run(download_threads, downloads.writer(sources.journal, n, fmt))
            try:
                first = await _first(chunks, n)
                response = web.StreamResponse(
                    headers={
                        "Content-Type": downloads.FORMATS[fmt],
                        "Content-Disposition": f'attachment; filename="survey-{n}{_dot(fmt)}"',
                    }
                )
                with contextlib.suppress(ConnectionError):
                    await response.prepare(request)
                    await _send(request, response, first, chunks, limits.send_stall_s)
            finally:
                await chunks.aclose()
        return response

    async def science_of(n: int) -> science.Made:
        try:
            return await made.get(n)
        except journaldata.NotFound as exc:
            raise Refused(404, str(exc)) from None
        except StoreError as exc:
            raise Refused(503, str(exc)) from None

    async def api_science(request: web.Request) -> web.Response:
        n = number(request.match_info["n"], "survey")
        found = await science_of(n)
        return web.json_response({**found.doc, **made.state(found)})

    async def product(request: web.Request) -> web.StreamResponse:
        n, name = number(request.match_info["n"], "survey"), request.match_info["name"]
        found = await science_of(n)
        part, kind = science.PRODUCTS[name]
        try:
            f = (found.directory / part / name).open("rb")
        except FileNotFoundError:
            why = found.doc[part].get("why") or "; ".join(found.doc[part].get("notes", []))
            raise Refused(404, f"survey {n}: no {name}{f': {why}' if why else ''}") from None
        with f:
            chunks = _read(f)
            response = web.StreamResponse(
                headers={
                    "Content-Type": kind,
                    "Content-Disposition": f'attachment; filename="survey-{n}-{name}"',
                }
            )
            with contextlib.suppress(ConnectionError):
                await response.prepare(request)
                await _send(request, response, await anext(chunks, None), chunks,
                            limits.send_stall_s)  # fmt: skip
        return response

    async def stop(app: web.Application) -> None:
        status.close()
        await asyncio.to_thread(made.close)
        if auth is not None:
            auth.close()
        download_threads.shutdown(wait=True, cancel_futures=True)

    app = web.Application(middlewares=[middleware(auth, set(sources.hosts), sources.journal)])
    app.on_response_prepare.append(add_headers)
    app.on_cleanup.append(stop)
    # GET only, HEAD too: a HEAD of a download would build it to send nothing.
    for path in pages:
        app.router.add_get(path, page, allow_head=False)
    for path, handler in [
        ("/api/status", api_status),
        ("/api/surveys", api_surveys),
        ("/api/surveys/{n}/casts", api_casts),
        ("/api/casts/{n}/profile", api_profile),
        ("/api/events", api_events),
        ("/api/latest", api_latest),
        ("/api/surveys/{n}/science", api_science),
        ("/download/survey/{n}/{name:" + PRODUCT_NAMES + "}", product),
        # The sonde's first: `3-sonde.csv` would otherwise be survey "3-sonde", as CSV.
        (r"/download/survey/{n}-{fmt:sonde\.csv|sonde\.nc}", download),
        (r"/download/survey/{n}.{fmt:csv|geojson|nc}", download),
    ]:
        app.router.add_get(path, handler, allow_head=False)
    return app


async def _read(f: IO[bytes]) -> AsyncIterator[bytes]:
    while chunk := await asyncio.to_thread(f.read, CHUNK):
        yield chunk


def _dot(fmt: str) -> str:
    """How a download's name ends: `.csv`, or `-sonde.csv` for the sonde's readings."""
    return f"-{fmt}" if fmt.startswith("sonde.") else f".{fmt}"


def split_listen(listen: str) -> tuple[str, int]:
    host, _, port = listen.rpartition(":")
    return host.strip("[]"), int(port)


async def serve(
    sources: Sources,
    listen: str,
    *,
    ready: Callable[[str, int], None],
    limits: Limits | None = None,
) -> None:
    """Serve until cancelled. OSError if the address cannot be bound. `ready` is told
    the address and how many connections the page will hold."""
    limits = limits or Limits()
    host, port = split_listen(listen)
    hosts = default_names(host, sources.hosts)
    app = build_app(dataclasses.replace(sources, hosts=frozenset(hosts)), limits)
    runner = web.AppRunner(app, access_log=None, handle_signals=False, shutdown_timeout=1.0)
    await runner.setup()
    listener: Listener | None = None
    try:
        assert runner.server is not None
        listener = Listener(runner.server, open_sockets(host, port), limits)
        listener.start()
        bound = listener.sockets[0].getsockname()[1]  # the real port when asked for port 0
        ready(f"{host if ':' not in host else f'[{host}]'}:{bound}", listener.connections.cap)
        await asyncio.Event().wait()
    finally:
        if listener is not None:
            await listener.close()
        await runner.cleanup()
