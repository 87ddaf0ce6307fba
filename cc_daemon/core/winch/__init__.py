"""The winch as the core sees it: its reported state, its interface, its physics (pure)."""
