"""`python -m cc_daemon` runs the command-line interface."""

from cc_daemon.cli.app import main

raise SystemExit(main())
