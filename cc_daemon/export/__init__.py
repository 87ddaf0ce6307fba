"""Getting the data out of the journal: CSV, GeoJSON and CF NetCDF writers.

This package owns the file formats scientists receive. Each writer takes
records from `cc_daemon.store.JournalReader` and a destination, and knows one
format's rules (RFC 4180 CSV, RFC 7946 GeoJSON, the CF conventions' profile
feature type). It never opens the journal itself and never writes to it.

Optional formats import their library when used, not when this package is
imported, and raise `OptionalDependencyError` with a command that installs it,
runnable as printed.
"""

import shlex
import sys

from cc_daemon.core.errors import CcDaemonError

# What each extra installs (as pyproject.toml's [project.optional-dependencies] says).
REQUIREMENTS = {"plot": "matplotlib>=3.8", "netcdf": "netCDF4>=1.6", "science": "numpy>=1.26"}


class OptionalDependencyError(CcDaemonError):
    """A feature needs an optional extra that is not installed; the message says
    how to install it into the very Python that runs cc-daemon."""

    def __init__(self, feature: str, module: str, extra: str) -> None:
        python = shlex.quote(sys.executable)
        requirement = shlex.quote(REQUIREMENTS.get(extra, module))
        super().__init__(
            f"{feature} needs the optional package {module!r}, which is not installed:"
            f" {python} -m pip install {requirement}"
            " (in a cc-daemon clone, `make extras` installs every optional package)"
        )
        self.feature = feature
        self.module = module
        self.extra = extra


__all__ = ["OptionalDependencyError"]
