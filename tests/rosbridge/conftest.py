from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest

from .server_fixture import RunningServer, running_server


@pytest.fixture
def srv(tmp_path: Path) -> Iterator[RunningServer]:
    with running_server(tmp_path) as s:
        yield s
