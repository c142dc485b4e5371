"""A running app (real simulator on loopback, real driver) shared by the REST tests."""

from __future__ import annotations

from tests.app_client import app_fixture

PILOT = "pilot-token-for-tests"
OBSERVER = "observer-token-for-tests"


# The app on its own simulator, shared by the REST tests of this directory.
api = app_fixture(PILOT, OBSERVER, sim_speed=4.0)
