"""cc-daemon: the companion-computer daemon of an autonomous survey boat."""

__version__ = "0.1.0"
