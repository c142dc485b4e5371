"""Shared fixtures: the shipped model and scenes rendered by the simulator."""

from __future__ import annotations

import math
import os
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from drone.sim.camera import Renderer
from drone.sim.world import COLOURS, SceneObject, World, load_world
from server.captioner import Captioner

# The shipped model; UAVC_MODEL_DIR (the server's setting) points the tests at another one.
MODEL_DIR = Path(
    os.environ.get("UAVC_MODEL_DIR", Path(__file__).resolve().parents[2] / "models" / "captioner")
)


@pytest.fixture(scope="session")
def model_dir() -> Path:
    return MODEL_DIR


@pytest.fixture(scope="session")
def captioner() -> Iterator[Captioner]:
    cap = Captioner.load(MODEL_DIR)
    yield cap
    cap.close()


@pytest.fixture(scope="session")
def indoor() -> World:
    return load_world("indoor")


def chair_scene(world: World, colour: str, bearing_deg: float, distance_m: float) -> np.ndarray:
    """The room with one chair, seen from (2, 3, 1) m facing +x, at the given bearing (left +)."""
    x0, y0, z0 = 2.0, 3.0, 1.0
    a = math.radians(bearing_deg)
    chair = SceneObject(
        id="chair1",
        kind="chair",
        colour=colour,
        bgr=COLOURS[colour],
        position=(x0 + distance_m * math.cos(a), y0 + distance_m * math.sin(a), 0.0),
        yaw_rad=math.pi,
        size=(0.45, 0.45, 0.9),
    )
    return Renderer(world.with_objects((chair,)), seed=3).render((x0, y0, z0, 0.0, 0.0, 0.0))
