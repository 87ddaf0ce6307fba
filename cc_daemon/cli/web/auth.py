"""The page's password: scrypt hashes for `[web] password_hash`, and HTTP basic auth.

The setting holds `scrypt$N$r$p$salt$hash` (base64), never the password. A
verified Authorization header is remembered by its SHA-256, so a phone polling
once a second costs one scrypt, not one a second.
"""

from __future__ import annotations

import base64
import binascii
import hashlib
import hmac
import os

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


class BasicAuth:
    """Checks `Authorization: Basic ...` headers against one password hash."""

    def __init__(self, setting: str) -> None:
        self._setting = setting
        self._good: list[bytes] = []

    def allows(self, header: str | None) -> bool:
        if not header or not header.startswith("Basic "):
            return False
        digest = hashlib.sha256(header.encode()).digest()
        if any(hmac.compare_digest(digest, seen) for seen in self._good):
            return True
        try:
            text = base64.b64decode(header[6:].strip(), validate=True).decode()
        except (ValueError, binascii.Error):
            return False
        _user, sep, password = text.partition(":")  # any user name: one password
        if not sep or not verify_password(password, self._setting):
            return False
        self._good = [*self._good[-(_REMEMBERED - 1) :], digest]
        return True
