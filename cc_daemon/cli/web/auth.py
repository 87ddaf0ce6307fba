"""The page's password: scrypt hashes for `[web] password_hash`, and HTTP basic auth.

The setting holds `scrypt$N$r$p$salt$hash` (base64), never the password. A
verified Authorization header is remembered by its SHA-256, so a phone polling
once a second costs one scrypt, not one a second.

A scrypt costs 16 MiB and about 50 ms on a Pi 4, so checking a password must
never run on the event loop: it runs on one thread of its own, one check at a
time, with at most `Limits.password_checks_waiting` queued; each client address
may fail only so often (`throttle.FailureBudget`), and beyond that is answered
429 without a scrypt. A logged-in page's requests meet neither: its header is
remembered.

The header is read as RFC 7235 and 7617 say: the scheme in any case; the
credentials in UTF-8, or Latin-1 where they are not UTF-8 (older browsers send
what the user typed in Latin-1).
"""

from __future__ import annotations

import asyncio
import base64
import binascii
import hashlib
import hmac
import math
import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

from cc_daemon.cli.web.policy import Limits
from cc_daemon.cli.web.throttle import FailureBudget

# 16 MiB and about 50 ms on a Pi 4: slow for a guesser, once per client for us.
N, R, P = 1 << 14, 8, 1
_KEY_BYTES = 32
_REMEMBERED = 64


def hash_password(password: str, *, salt: bytes | None = None) -> str:
    salt = os.urandom(16) if salt is None else salt
    key = hashlib.scrypt(password.encode(), salt=salt, n=N, r=R, p=P, dklen=_KEY_BYTES)
    return "$".join(["scrypt", str(N), str(R), str(P), base64.b64encode(salt).decode(), _b64(key)])


def _b64(data: bytes) -> str:
    return base64.b64encode(data).decode()


def verify_password(password: str, setting: str) -> bool:
    """True if `password` is the one `setting` (a `hash_password` string) was made from."""
    try:
        scheme, n, r, p, salt, key = setting.split("$")
        expected = base64.b64decode(key, validate=True)
        derived = hashlib.scrypt(
            password.encode(),
            salt=base64.b64decode(salt, validate=True),
            n=int(n),
            r=int(r),
            p=int(p),
            dklen=len(expected),
            maxmem=1 << 26,
        )
    except (ValueError, binascii.Error):
        return False
    return scheme == "scrypt" and hmac.compare_digest(derived, expected)


class MalformedHeader(ValueError):
    """An Authorization header no browser sends (bytes beyond ASCII): a 400."""


def basic_credentials(header: str) -> tuple[str, str] | None:
    """(user, password) of a `Basic` header; None if it is another scheme or unreadable.

    MalformedHeader if the header holds anything but ASCII (aiohttp hands such
    bytes over as surrogates)."""
    if not header.isascii():
        raise MalformedHeader("the Authorization header is not ASCII")
    scheme, _, token = header.strip().partition(" ")
    if scheme.lower() != "basic":  # RFC 7235 2.1: the scheme is case-insensitive
        return None
    try:
        raw = base64.b64decode(token.strip(), validate=True)
    except (ValueError, binascii.Error):
        return None
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError:
        text = raw.decode("latin-1")  # every byte is a Latin-1 character
    user, sep, password = text.partition(":")
    return (user, password) if sep else None


@dataclass(frozen=True, slots=True)
class Refusal:
    """Why a request may not in: 400 (a malformed header), 401 or 429."""

    status: int
    message: str
    retry_after_s: int | None = None


_ASK = Refusal(401, "the field page needs its password")


class BasicAuth:
    """Checks `Authorization: Basic ...` headers against one password hash."""

    def __init__(self, setting: str, limits: Limits | None = None) -> None:
        limits = limits or Limits()
        self._setting = setting
        self._good: list[bytes] = []
        self._budget = FailureBudget(limits.password_burst, limits.password_refill_s)
        self._most_waiting = limits.password_checks_waiting
        self._waiting = 0
        self._thread = ThreadPoolExecutor(1, thread_name_prefix="password")

    def close(self) -> None:
        self._thread.shutdown(wait=False, cancel_futures=True)

    def remembered(self, header: str) -> bool:
        digest = hashlib.sha256(header.encode("ascii")).digest()
        return any(hmac.compare_digest(digest, seen) for seen in self._good)

    async def check(self, header: str | None, client: str) -> Refusal | None:
        """None if the header holds the password; else why not."""
        if not header:
            return _ASK
        try:
            found = basic_credentials(header)
        except MalformedHeader as exc:
            return Refusal(400, str(exc))
        if found is None:
            return _ASK
        if self.remembered(header):
            return None
        if self._waiting >= self._most_waiting:
            return Refusal(429, "too many password checks at once: try again", 1)
        wait_s = self._budget.take(client)
        if wait_s:
            return Refusal(429, "too many wrong passwords: wait", max(1, math.ceil(wait_s)))
        self._waiting += 1
        try:
            right = await asyncio.get_running_loop().run_in_executor(
                self._thread, verify_password, found[1], self._setting
            )
        finally:
            self._waiting -= 1
        if not right:
            return _ASK
        self._budget.refund(client)
        digest = hashlib.sha256(header.encode("ascii")).digest()
        self._good = [*self._good[-(_REMEMBERED - 1) :], digest]
        return None
