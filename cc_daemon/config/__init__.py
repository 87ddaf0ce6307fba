"""The daemon's configuration: its schema, where values come from, and what a bad one says.

- `schema`: every key (names, types, defaults, allowed ranges, the combinations that
  cannot work together) and the frozen `Settings`;
- `rules`: the validators and bounded types the sections share;
- `loading`: the sources (command-line flag > environment > TOML file > default)
  and the wording of errors: one line per problem naming the dotted key, the value
  given, what is allowed and where the value came from.

It must never open a device, start a task, configure logging or exit the process:
it reads at most one TOML file and the environment mapping it is given, and either
returns a frozen `Settings` or raises `ConfigError`. Deciding the exit status
(2 for a bad configuration) is the command line's job.
"""

from cc_daemon.config.loading import (
    DEFAULT_SEARCH_PATHS,
    ENV_NESTED_DELIMITER,
    ENV_PREFIX,
    FLAG_NAMES,
    load_settings,
)
from cc_daemon.config.profile import ProfileSettings
from cc_daemon.config.rules import STANDARD_BAUDRATES
from cc_daemon.config.schema import (
    CastSettings,
    LogSettings,
    SerialSettings,
    Settings,
    SonarSettings,
    StatusSettings,
    StoreSettings,
    WebSettings,
)
from cc_daemon.config.winch import WinchGpioSettings, WinchSettings, WinchSimSettings

__all__ = [
    "DEFAULT_SEARCH_PATHS",
    "ENV_NESTED_DELIMITER",
    "ENV_PREFIX",
    "FLAG_NAMES",
    "STANDARD_BAUDRATES",
    "CastSettings",
    "LogSettings",
    "ProfileSettings",
    "SerialSettings",
    "Settings",
    "SonarSettings",
    "StatusSettings",
    "StoreSettings",
    "WebSettings",
    "WinchGpioSettings",
    "WinchSettings",
    "WinchSimSettings",
    "load_settings",
]
