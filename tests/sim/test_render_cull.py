"""The renderer's culling and still-camera frames change no pixel: every seeded pose in both
worlds renders the same image and id buffer as the renderer drawing everything (``cull=False``),
and a camera standing still gets the frames it would get drawn afresh."""

from __future__ import annotations

import numpy as np
import pytest

from drone.sim.camera import Renderer
from drone.sim.world import load_world
from tests.sim.camera_poses import seeded_poses


@pytest.mark.parametrize("world_name", ["indoor", "outdoor"])
def test_culled_render_is_pixel_identical_to_drawing_everything(world_name: str) -> None:
    world = load_world(world_name)
    culled = Renderer(world, seed=3)
    full = Renderer(world, seed=3, cull=False)
    differing: list[int] = []
    for k, pose in enumerate(seeded_poses(world, 90, seed=11)):
        brightness = (1.0, 0.6, 1.3)[k % 3]
        a = culled.render(pose, brightness=brightness, frame=k)
        b = full.render(pose, brightness=brightness, frame=k)
        if not np.array_equal(a, b) or not np.array_equal(
            culled.render_ids(pose), full.render_ids(pose)
        ):
            differing.append(k)
    assert differing == []


def test_visible_objects_unchanged_by_culling() -> None:
    world = load_world("indoor")
    culled, full = Renderer(world, seed=0), Renderer(world, seed=0, cull=False)
    for pose in seeded_poses(world, 30, seed=5):
        assert culled.visible(pose) == full.visible(pose)


def test_a_still_camera_gets_the_frames_drawn_afresh() -> None:
    world = load_world("indoor")
    pose = (4.0, 2.0, 0.0, 0.0, 0.0, 1.0)
    still = Renderer(world, seed=2)
    frames = [still.render(pose, frame=k) for k in range(10)]
    for k, img in enumerate(frames):
        fresh = Renderer(world, seed=2).render(pose, frame=k)
        assert np.array_equal(img, fresh), k
    # the patterns differ, and a repeat is the caller's own copy
    assert not np.array_equal(frames[0], frames[1])
    frames[4][:] = 0
    assert np.array_equal(still.render(pose, frame=8), frames[0])
    # brightness is part of the frame; moving on draws the new pose
    assert np.array_equal(
        still.render(pose, brightness=0.5, frame=0),
        Renderer(world, seed=2).render(pose, brightness=0.5, frame=0),
    )
    moved = (4.5, 2.0, 0.0, 0.0, 0.0, 1.0)
    assert np.array_equal(
        still.render(moved, frame=0), Renderer(world, seed=2).render(moved, frame=0)
    )
