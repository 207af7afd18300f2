"""Fixtures shared with the factory's tests: the session's short shirt walk (a real simulation),
from which a tiny real capture is rendered once per session."""

import pytest

from tests.factory.conftest import shirt_run

__all__ = ["shirt_run", "capture_folder"]  # pytest fixtures, found by name


@pytest.fixture(scope="session")
def capture_folder(shirt_run, tmp_path_factory):
    """Frames 3 and 4 of the shirt walk from three cameras at 96 x 64 (Workbench): cameras.json,
    images, depth and ground truth per camera, garment.npz, template.npz."""
    from factory.dataset import RenderSettings, capture

    _, sim, _ = shirt_run
    tiny = RenderSettings(resolution=(96, 64), engine="WORKBENCH", samples=1, denoise=False)
    return capture("shirt", "walk", tmp_path_factory.mktemp("capture"), frames=2, first_frame=3, cameras=3,
                   resolution=(96, 64), render=tiny, progress=False, simulation=sim)
