"""``python -m server`` is the ``uav-console`` command."""

import os
import sys

from server import timewarp

# First, before any module captures ``time.monotonic``: ``serve --clock-speed N`` (and its
# vehicle processes, through the environment) run N times faster than the wall clock.
timewarp.install_from(sys.argv[1:], os.environ)

from server.cli import main  # noqa: E402

raise SystemExit(main())
