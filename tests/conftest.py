"""Shared fixtures. ``shared_dir`` finds ../shared (beside the checkout); tests that need it skip
with a reason when it is absent, unless CALIBGRAPH_SHARED_REQUIRED=1 (CI), where they fail."""

import os
import shutil
from pathlib import Path

# MuJoCo binds its GL backend when first imported; a test module that imports mujoco (directly or
# via franky_sim) during collection would otherwise get GLFW, which aborts without a display.
os.environ.setdefault("MUJOCO_GL", "egl")
os.environ.setdefault("PYOPENGL_PLATFORM", os.environ["MUJOCO_GL"])

import pytest

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="session")
def shared_dir() -> Path:
    candidates = [REPO.parent / "shared", REPO / "shared"]
    env = os.environ.get("CALIBGRAPH_SHARED")
    if env:
        candidates.insert(0, Path(env))
    for c in candidates:
        if (c / "datasets").is_dir():
            return c
    msg = "../shared (real datasets) is not beside this checkout"
    if os.environ.get("CALIBGRAPH_SHARED_REQUIRED") == "1":
        pytest.fail(msg + " and CALIBGRAPH_SHARED_REQUIRED=1")
    pytest.skip(msg)



@pytest.fixture(scope="module")
def rct_dir(shared_dir, tmp_path_factory) -> Path:
    """A private copy of the real RCT ChArUco dataset (the detection cache is written next to the
    data, and ../shared is read-only); one copy per test module."""
    src = shared_dir / "datasets" / "rct_static_camera_charuco"
    if not (src / "cal_data.yaml").is_file():
        pytest.skip(f"{src} is missing")
    dst = tmp_path_factory.mktemp("rct") / "rct_static_camera_charuco"
    shutil.copytree(src, dst)
    return dst
