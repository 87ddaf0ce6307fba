"""Winch backends behind one small interface (`Winch`)."""

from cc_daemon.winch.base import Winch, WinchStatus

__all__ = ["Winch", "WinchStatus"]
