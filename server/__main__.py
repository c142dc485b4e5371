"""``python -m server`` is the ``uav-console`` command."""

from server.cli import main

raise SystemExit(main())
