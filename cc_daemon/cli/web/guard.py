"""What every request passes before its handler, and how every refusal is answered.

This module owns the page's middleware: the `Host` header first (a page from
elsewhere that had its name point at the Pi, DNS rebinding, names a host that
is not the Pi's: 421), then the password (`auth`: 400, 401, 429), then the
handler, whose failures all become one JSON line, `{"error": "..."}`, with the
status that says why (`Refused`, raised by the handlers; aiohttp's 404 and 405;
500 for anything else, logged), never a traceback and never a filesystem path.
The page's headers go on every answer, streamed or not (`add_headers`).

It also marks each request's start and end on its connection
(`listener.Guarded`), after the answer is written, so a connection's idle
time is counted from then.
"""

from __future__ import annotations

import contextlib
import ipaddress
import re
import socket
from collections.abc import Awaitable, Callable, Iterable
from pathlib import Path
from typing import Any

import structlog
from aiohttp import web

from cc_daemon.cli.web.auth import BasicAuth
from cc_daemon.cli.web.listener import Guarded
from cc_daemon.cli.web.policy import HEADERS

log = structlog.get_logger(__name__)

Handler = Callable[[web.Request], Awaitable[web.StreamResponse]]
# A number in a path or query: ASCII digits, fewer than 19 of them, so it fits
# SQLite's 64-bit integer ('²'.isdigit() is true, and int() refuses it).
_NUMBER = re.compile(r"[0-9]{1,18}")
# Anything that looks like an absolute path of two parts or more: never sent.
_PATH = re.compile(r"(?<![\w.])/(?:[\w.@+-]+/)+[\w.@+-]*")


class Refused(Exception):
    """An answer other than 200, raised by a handler: its status and one line."""

    def __init__(self, status: int, message: str, headers: dict[str, str] | None = None) -> None:
        super().__init__(message)
        self.status = status
        self.message = message
        self.headers = headers or {}


def number(text: str, what: str) -> int:
    """`text` as a survey's or a cast's number; Refused(400) if it is not one."""
    if not _NUMBER.fullmatch(text):
        shown = text if len(text) <= 24 else f"{text[:20]}... ({len(text)} characters)"
        raise Refused(400, f"{what} {shown!r}: a {what}'s number is 1 to 18 digits, e.g. 3")
    return int(text)


def default_names(listen_host: str, extra: Iterable[str] = ()) -> set[str]:
    """The host names the page answers to: localhost, this computer's name (and
    its mDNS `.local`), the listen address if it is a name, and `extra`
    (`[web] hosts`). Any IP address is answered too: a rebinding needs a name."""
    here = socket.gethostname()
    names = {"localhost", here, f"{here}.local", listen_host, *extra}
    return {n.lower().rstrip(".") for n in names if n}


def host_of(header: str) -> str | None:
    """The host of a `Host` header, lower case, without port or brackets; None if
    the header is not a host."""
    if not header.isascii():
        return None
    text = header.strip().lower()
    if text.startswith("["):
        host, sep, rest = text[1:].partition("]")
        return host if sep and (not rest or rest[:1] == ":") else None
    host, _, port = text.partition(":")
    if port and not port.isdigit():
        return None
    return host.rstrip(".") or None


def allowed_host(header: str | None, names: set[str]) -> bool:
    if header is None:  # HTTP/1.0 without Host: no browser, so no rebinding
        return True
    host = host_of(header)
    if host is None:
        return False
    try:
        ipaddress.ip_address(host)
    except ValueError:
        return host in names
    return True


def without_paths(message: str, journal: Path) -> str:
    """`message` with the journal's path, and any other, put in words."""
    for form in {str(journal.resolve()), str(journal)}:
        message = message.replace(form, "the journal")
    message = message.replace("no journal at the journal", "no journal")  # none yet
    return _PATH.sub("(a file)", message)


async def add_headers(request: web.Request, response: web.StreamResponse) -> None:
    """`on_response_prepare`: the page's headers on every answer it writes."""
    response.headers.update(HEADERS)


def middleware(auth: BasicAuth | None, names: set[str], journal: Path) -> Any:
    """The page's one middleware (see the module's docstring)."""

    def answer(status: int, message: str, headers: dict[str, str] | None = None) -> web.Response:
        text = without_paths(message, journal).replace("\n", " ")
        return web.json_response({"error": text}, status=status, headers=headers)

    async def admit(request: web.Request, handler: Handler) -> web.StreamResponse:
        if not allowed_host(request.headers.get("Host"), names):
            return answer(
                421, "this page answers to the Pi's own names and addresses only ([web] hosts)"
            )
        if auth is not None:
            refusal = await auth.check(request.headers.get("Authorization"), request.remote or "")
            if refusal is not None:
                headers = {}
                if refusal.status == 401:
                    headers["WWW-Authenticate"] = 'Basic realm="cc-daemon", charset="UTF-8"'
                if refusal.retry_after_s is not None:
                    headers["Retry-After"] = str(refusal.retry_after_s)
                return answer(refusal.status, refusal.message, headers)
        try:
            return await handler(request)
        except Refused as exc:
            return answer(exc.status, exc.message, exc.headers)
        except web.HTTPException as exc:  # the router's 404 and 405
            allow = {"Allow": exc.headers["Allow"]} if "Allow" in exc.headers else {}
            return answer(exc.status, exc.reason, allow)
        except Exception as exc:
            route = request.match_info.route.resource
            log.error(
                "a request failed",
                route=route.canonical if route is not None else "",
                error=type(exc).__name__,
                exc_info=exc,
            )
            return answer(500, "the page failed to answer this (its log says why)")

    @web.middleware
    async def guard(request: web.Request, handler: Handler) -> web.StreamResponse:
        connection = request.protocol if isinstance(request.protocol, Guarded) else None
        if connection is not None:
            connection.request_started()
        try:
            response = await admit(request, handler)
            with contextlib.suppress(ConnectionError):  # the client left: nothing to say
                await response.prepare(request)
                await response.write_eof()
            return response
        finally:
            if connection is not None:
                connection.request_ended()

    return guard
