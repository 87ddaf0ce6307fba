"""The project's exceptions: one root, a handful of kinds.

Two families matter most (as in h11): errors that say *the peer sent bad data*
(`FrameError`) and errors that say *the caller misused the API* (`FieldError`,
`TransitionError`). Everything derives from `CcDaemonError` so a top level can
catch "ours" without catching bugs in libraries.
"""

from __future__ import annotations


class CcDaemonError(Exception):
    """Root of every exception cc-daemon raises on purpose."""


class ProtocolError(CcDaemonError):
    """Something about the autopilot link protocol is wrong."""


class FrameError(ProtocolError, ValueError):
    """The peer sent bytes that do not form a valid frame."""

    def __init__(self, kind: str, detail: str) -> None:
        super().__init__(f"{kind}: {detail}")
        self.kind = kind
        self.detail = detail


class FieldError(ProtocolError, ValueError):
    """A message was built with a field outside what the wire can carry."""

    def __init__(self, field: str, value: object, allowed: str) -> None:
        super().__init__(f"{field}={value!r} is invalid: allowed {allowed}")
        self.field = field
        self.value = value
        self.allowed = allowed


class ConfigError(CcDaemonError):
    """The configuration is invalid; the message names key, value and what is allowed."""


class WinchFault(CcDaemonError):
    """The winch cannot do what it was asked (stall, lost encoder, no home)."""


class TransitionError(CcDaemonError, RuntimeError):
    """A state machine was asked for a transition its table forbids: a bug."""
