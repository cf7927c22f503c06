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


def _shared_candidates() -> list:
    candidates = [REPO.parent / "shared", REPO / "shared"]
    env = os.environ.get("CALIBGRAPH_SHARED")
    if env:
        candidates.insert(0, Path(env))
    return candidates


@pytest.fixture(scope="session")
def shared_dir() -> Path:
    for c in _shared_candidates():
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


@pytest.fixture(autouse=True, scope="session")
def _tests_never_write_into_shared():
    """Tests never write into ../shared (CI's copy is read-only by its mode bits, which root ignores):
    in this process every calibgraph file write (``atomic_write_via``, which every writer and the
    detection cache go through) and every dataset lock under ../shared fails the test that made it.
    Solve a copy instead (the ``rct_dir`` fixture)."""
    import calibgraph.io.files as files
    import calibgraph.io.lock as lock

    roots = [Path(os.path.realpath(c)) for c in _shared_candidates() if (c / "datasets").is_dir()]
    real_write, real_lock = files.atomic_write_via, lock.lock_folder

    def refuse(path):
        p = Path(os.path.realpath(path))
        if any(p == r or r in p.parents for r in roots):
            raise AssertionError(f"a test writes into ../shared ({path}); solve a copy of it (the rct_dir fixture)")

    def write(path, *a, **kw):
        refuse(path)
        return real_write(path, *a, **kw)

    def take(out, *a, **kw):
        refuse(out)
        return real_lock(out, *a, **kw)

    files.atomic_write_via, lock.lock_folder = write, take
    yield
    files.atomic_write_via, lock.lock_folder = real_write, real_lock
