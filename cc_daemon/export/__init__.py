"""Getting the data out of the journal: CSV, GeoJSON and CF NetCDF writers.

This package owns the file formats scientists receive. Each writer takes
records from `cc_daemon.store.JournalReader` and a destination, and knows one
format's rules (RFC 4180 CSV, RFC 7946 GeoJSON, the CF conventions' profile
feature type). It never opens the journal itself and never writes to it.

Optional formats import their library when used, not when this package is
imported, and raise `OptionalDependencyError` naming the extra to install.
"""

from cc_daemon.errors import CcDaemonError


class OptionalDependencyError(CcDaemonError):
    """A feature needs an optional extra that is not installed; the message says which."""

    def __init__(self, feature: str, module: str, extra: str) -> None:
        super().__init__(
            f"{feature} needs the optional package {module!r}, which is not installed:"
            f" pip install 'cc-daemon[{extra}]'"
        )
        self.feature = feature
        self.module = module
        self.extra = extra


__all__ = ["OptionalDependencyError"]
