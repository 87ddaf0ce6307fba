"""SIGHUP: what a re-read configuration changes, and what of it can apply live.

`plan_reload(old, new)` is pure: it compares the settings in use with the ones
just read and returns the settings to run with from now on (the live keys
from the new file, every other key as it was), the live keys that changed and
the keys that changed but need a restart. `Reloader` carries a reload out with
what it is given (how to read the configuration, how to set up logging, the
daemon) and says what happened, in the log and the journal.

Live: `log.*`, `cast.*` (for the next cast: a running cast keeps the values it
started with) and `store.telemetry_rate_hz`. Everything else (the port and its
line settings, the winch, the journal's path) is bound to a device or a file
opened at start, so it needs a restart.

It must never raise into the event loop (a reload is never worth the daemon),
never interrupt a cast, and never leave the daemon on a half-applied
configuration: a file that does not validate, or live values that cannot work
with the values kept, change nothing.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass
from typing import Any, Protocol

import structlog
from pydantic import ValidationError

from cc_daemon.config import Settings
from cc_daemon.core.errors import ConfigError

__all__ = ["LIVE_KEYS", "ReloadPlan", "ReloadRefused", "Reloader", "plan_reload"]

_log = structlog.get_logger("cc_daemon.reload")

# Dotted keys (or section prefixes ending in ".") that a reload applies at once.
LIVE_KEYS: tuple[str, ...] = ("log.", "cast.", "store.telemetry_rate_hz")


class ReloadRefused(ValueError):
    """The new live values cannot work with the values a reload keeps."""


@dataclass(frozen=True, slots=True)
class ReloadPlan:
    settings: Settings  # what to run with from now on
    applied: tuple[str, ...]  # live keys whose value changed, dotted, in schema order
    needs_restart: tuple[str, ...]  # keys that changed but keep their old value until a restart

    @property
    def logging_changed(self) -> bool:
        return any(key.startswith("log.") for key in self.applied)


def _leaves(data: Mapping[str, Any], prefix: str = "") -> Iterator[tuple[str, Any]]:
    for name, value in data.items():
        if isinstance(value, Mapping):
            yield from _leaves(value, f"{prefix}{name}.")
        else:
            yield f"{prefix}{name}", value


def is_live(key: str) -> bool:
    return any(key == live or (live.endswith(".") and key.startswith(live)) for live in LIVE_KEYS)


def _set(tree: dict[str, Any], key: str, value: Any) -> None:
    *path, last = key.split(".")
    for part in path:
        tree = tree[part]
    tree[last] = value


def plan_reload(old: Settings, new: Settings) -> ReloadPlan:
    """What to run with after a reload from `old` to `new` (see the module docstring).

    Raises ReloadRefused if the live values of `new` cannot work with the
    restart-only values of `old` (e.g. a target depth beyond the line in use).
    """
    before = dict(_leaves(old.model_dump()))
    after = dict(_leaves(new.model_dump()))
    changed = [key for key in after if after[key] != before.get(key)]
    applied = tuple(key for key in changed if is_live(key))
    needs_restart = tuple(key for key in changed if not is_live(key))
    effective = old.model_dump()
    for key in applied:
        _set(effective, key, after[key])
    try:
        settings = Settings.model_validate(effective)
    except ValidationError as exc:
        kept = ", ".join(f"{key} = {before[key]!r}" for key in needs_restart)
        reasons = "; ".join(error["msg"] for error in exc.errors())
        raise ReloadRefused(
            f"{reasons} (with the values kept until a restart{': ' + kept if kept else ''})"
        ) from None
    # The new file's origins, so a later message can say where a value came from.
    settings._source_file = new.source_file
    settings._merged, settings._origins = new._merged, new._origins
    return ReloadPlan(settings, applied, needs_restart)


class ReloadTarget(Protocol):
    """What a reload needs from the daemon (`cc_daemon.daemon.service.Daemon`)."""

    settings: Settings

    @property
    def shutting_down(self) -> bool: ...

    def reload(self, settings: Settings, applied: tuple[str, ...]) -> None: ...

    def record_event(self, kind: str, **detail: Any) -> None: ...


class Reloader:
    """Carries out a SIGHUP: read, compare, apply what can be applied, say the rest.

    `load` reads the configuration as at start (file, environment, flags) and
    raises ConfigError; `configure_logging(settings)` sets logging up from it.
    """

    def __init__(
        self,
        target: ReloadTarget,
        load: Callable[[], Settings],
        configure_logging: Callable[[Settings], None],
    ) -> None:
        self._target = target
        self._load = load
        self._configure_logging = configure_logging

    def __call__(self) -> None:
        try:
            self._reload()
        except Exception:  # a reload is never worth the daemon
            _log.exception("reload failed; the configuration in use is unchanged")

    def _reload(self) -> None:
        target = self._target
        if target.shutting_down:
            _log.info("SIGHUP during shutdown: ignored; the shutdown goes on")
            return
        try:
            new = self._load()
        except ConfigError as exc:
            self._refuse(str(exc).splitlines())
            return
        try:
            plan = plan_reload(target.settings, new)
        except ReloadRefused as exc:
            self._refuse([f"cc-daemon: cannot reload: {exc}"])
            return
        if plan.logging_changed:
            self._configure_logging(plan.settings)
        for key in plan.needs_restart:
            _log.warning(
                "reload: this key needs a restart to change; keeping the value in use",
                key=key,
                in_use=_value(target.settings, key),
                in_file=_value(new, key),
            )
        target.reload(plan.settings, plan.applied)
        if plan.applied:
            _log.info(
                "configuration reloaded",
                applied=list(plan.applied),
                needs_restart=list(plan.needs_restart),
                source=str(new.source_file) if new.source_file else None,
            )
        elif not plan.needs_restart:
            _log.info("configuration reloaded: unchanged")

    def _refuse(self, problems: list[str]) -> None:
        # The same lines --config prints at start, one field per line.
        _log.error("reload refused: keeping the configuration in use", problems=problems)
        self._target.record_event("config_reload_refused", problems=problems)


def _value(settings: Settings, dotted: str) -> Any:
    node: Any = settings
    for part in dotted.split("."):
        node = getattr(node, part)
    return str(node) if node is not None and not isinstance(node, int | float | bool) else node
