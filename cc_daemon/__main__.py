"""`python -m cc_daemon` runs the command-line interface."""

from cc_daemon.cli import main

raise SystemExit(main())
