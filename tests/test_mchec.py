"""MC-HEC (Multi-Camera-Hand-Eye-Calibration) layout: import of a folder written the way that
project's README and code lay it out, export of a captured dataset, and the round trip."""

import numpy as np
import pytest

from calibgraph.acquire.run import run_acquisition
from calibgraph.core.errors import InputError
from calibgraph.io.layouts import load_dataset
from calibgraph.io.peer_mchec import is_mchec_dataset, load_mchec_dataset, mchec_target
from calibgraph.report.mchec_export import export_mchec
from calibgraph.sim.fakes import make_fake_cell

INFO = """# Number of cameras you want to calibrate
number_of_cameras: 2
# Camera folder name where pose and image subfolders are located
camera_folder_prefix: camera
# Pattern type used
pattern_type: checkerboard

# Number of rows
number_of_rows: 4
# Number of columns
number_of_columns: 3
# Pattern size
size: 0.05

# Resize factor
resize_factor: 1
# Store reprojected corners: 0 to remove visualization, 1 if you want to store them
visual_error: 1
# Calibration type: 0 eye-in-hand, 1 eye-on-base
calibration_setup: 1
"""

INTR = """fx: 1371.02278154
fy: 1372.5
cx: 960.5
cy: 540.5
has_dist_coeff: 1
dist_k0: 0.11
dist_k1: -0.22
dist_px: 0.001
dist_py: 0.002
dist_k2: 0.03
dist_k3: 0.004
dist_k4: 0.005
dist_k5: 0.006
img_width: 1920
img_height: 1080"""

POSE_SPACE = """-7.660727453525862929e-01 -6.427537339110764858e-01 -4.317074486639985100e-04 -4.680410340634429400e-01
-6.427536729537794979e-01 7.660728647661733115e-01 -2.859604420198166158e-04 -3.925987470256024348e-01
5.145215037980239037e-04 5.841504738993030690e-05 -9.999998659276434498e-01 4.388789969200312391e-01
0.000000000000000000e+00 0.000000000000000000e+00 0.000000000000000000e+00 1.000000000000000000e+00
"""


def _mini_mchec(root):
    import cv2

    root.mkdir()
    (root / "CalibrationInfo.yaml").write_text(INFO)
    for c in ("camera1", "camera2"):
        (root / c / "image").mkdir(parents=True)
        (root / c / "pose").mkdir()
        (root / c / "intrinsic_pars_file.yaml").write_text(INTR)
        for k in (1, 2, 3):
            # images of the intrinsics' size (1920x1080), each capture its own
            cv2.imwrite(str(root / c / "image" / f"{k:04d}.png"), np.full((1080, 1920), 10 * k, np.uint8))
            text = POSE_SPACE if k != 2 else POSE_SPACE.replace(" ", ",")  # MC-HEC reads both delimiters
            (root / c / "pose" / f"{k:04d}.csv").write_text(text)
    return root


def test_import_follows_mchec_conventions(tmp_path):
    root = _mini_mchec(tmp_path / "mc")
    assert is_mchec_dataset(root) and not is_mchec_dataset(tmp_path)
    ds = load_mchec_dataset(root)
    # number_of_rows = corners along a row (cv::Size width) = calibgraph cols
    assert (ds.target.rows, ds.target.cols, ds.target.pitch_m) == (3, 4, 0.05)
    assert ds.mode == "eye_to_hand"
    intr = ds.cameras["camera1"]
    np.testing.assert_allclose(intr.K, [[1371.02278154, 0, 960.5], [0, 1372.5, 540.5], [0, 0, 1]])
    np.testing.assert_allclose(intr.dist, [0.11, -0.22, 0.001, 0.002, 0.03, 0.004, 0.005, 0.006])
    assert (intr.width_px, intr.height_px) == (1920, 1080)
    assert [c.index for c in ds.captures] == [1, 2, 3]
    T = np.array([[float(x) for x in ln.split()] for ln in POSE_SPACE.strip().splitlines()])
    for cap in ds.captures:
        np.testing.assert_allclose(cap.T_base_flange, T, atol=1e-6)
    assert len(ds.views) == 6 and all(v.ids is None for v in ds.views)
    assert {v.image for v in ds.views if v.capture == 2} == {"camera1/image/0002.png", "camera2/image/0002.png"}
    # the generic loader dispatches to it
    assert len(load_dataset(root).captures) == 3


def test_board_frame_is_mchec_object_points():
    info = {"number_of_rows": 4, "number_of_columns": 3, "size": 0.05}
    t = mchec_target(info)
    # MC-HEC Detector::getObjectPoints, transcribed: for i < NumCol, for j < NumRow: (j*size, i*size, 0)
    obj = [(j * info["size"], i * info["size"], 0.0) for i in range(info["number_of_columns"])
           for j in range(info["number_of_rows"])]
    np.testing.assert_allclose(t.points_board_m, obj)
    with pytest.raises(InputError, match="checkerboards"):
        mchec_target({**info, "pattern_type": "charuco"})


def test_import_errors_are_actionable(tmp_path):
    root = _mini_mchec(tmp_path / "mc")
    (root / "camera2" / "image" / "0003.png").unlink()
    with pytest.raises(InputError, match="camera2.*2 images but camera1/pose has 3"):
        load_mchec_dataset(root)
    root2 = _mini_mchec(tmp_path / "mc2")
    (root2 / "camera1" / "pose" / "0002.csv").write_text("1 0 0\n0 1 0\n")
    ds = load_mchec_dataset(root2)
    assert [c.index for c in ds.captures] == [1, 3] and "0002.csv" in ds.problems[0][0]
    (root2 / "CalibrationInfo.yaml").write_text(INFO.replace("number_of_cameras: 2", "number_of_cameras: 3"))
    with pytest.raises(InputError, match="camera3: missing"):
        load_mchec_dataset(root2)


def test_export_then_import_round_trip(tmp_path):
    cell = make_fake_cell(n_cameras=3, n_poses=8, seed=21, render=True, image_size=(320, 240))
    import cv2

    def detector(img, target, intr):
        ok, c = cv2.findChessboardCorners(img, (target.cols, target.rows))
        return (np.arange(len(c)), c.reshape(-1, 2)) if ok else None

    rep = run_acquisition(cell.robot, cell.cameras, cell.trajectory, tmp_path / "ds", cell.target, detector=detector,
                          progress=False)
    src = load_dataset(tmp_path / "ds")
    n_missing = len(src.captures) * 3 - len(src.views)
    assert rep.captured == len(src.captures) and n_missing > 0  # some cameras missed some captures
    out = export_mchec(tmp_path / "ds", tmp_path / "mc")
    # MC-HEC invariants: every camera folder has one image and one pose per waypoint, names aligned
    for k in (1, 2, 3):
        imgs = sorted(p.name for p in (out / f"camera{k}" / "image").iterdir())
        poses = sorted(p.name for p in (out / f"camera{k}" / "pose").iterdir())
        assert len(imgs) == len(poses) == len(src.captures)
        assert [p[:-4] for p in imgs] == [p[:-4] for p in poses]
    assert not [p for p in out.iterdir() if p.name.startswith("camera") and not p.is_dir()]
    back = load_mchec_dataset(out)
    assert back.target == src.target and back.mode == src.mode
    assert sorted(back.cameras) == sorted(src.cameras)
    for c in src.cameras:
        np.testing.assert_allclose(back.cameras[c].K, src.cameras[c].K)
        np.testing.assert_allclose(back.cameras[c].dist8, src.cameras[c].dist8)
    assert [c.index for c in back.captures] == [c.index for c in src.captures]
    for a, b in zip(src.captures, back.captures):
        np.testing.assert_allclose(b.T_base_flange, a.T_base_flange, atol=1e-15)
    # same views (placeholders for missed captures are not views), same pixels
    assert {(v.camera, v.capture) for v in back.views} == {(v.camera, v.capture) for v in src.views}
    by_key = {(v.camera, v.capture): v for v in src.views}
    for v in back.views:
        assert (out / v.image).read_bytes() == (tmp_path / "ds" / by_key[(v.camera, v.capture)].image).read_bytes()
    # exporting the imported dataset reproduces the same files (the layout is a fixed point)
    out2 = export_mchec(back, tmp_path / "mc2")
    files = sorted(p.relative_to(out).as_posix() for p in out.rglob("*") if p.is_file())
    assert files == sorted(p.relative_to(out2).as_posix() for p in out2.rglob("*") if p.is_file())
    for f in files:
        if f.endswith(".csv"):  # poses are re-orthonormalised on reading: equal to the last bit or two
            from calibgraph.io.peer_mchec import read_mchec_pose

            np.testing.assert_allclose(read_mchec_pose(out / f), read_mchec_pose(out2 / f), atol=1e-15)
        else:
            assert (out / f).read_bytes() == (out2 / f).read_bytes(), f
    with pytest.raises(InputError, match="not empty"):
        export_mchec(back, tmp_path / "mc2")


def test_a_truncated_image_costs_one_view(tmp_path):
    """Issue 26: in the MC-HEC layout too, an unreadable image is a warning naming the file and one
    view fewer; the solve succeeds from the rest (it used to abort)."""
    import subprocess
    import sys

    import cv2

    cell = make_fake_cell(n_cameras=2, n_poses=12, seed=3, render=True)

    def detector(img, target, intr):
        ok, c = cv2.findChessboardCorners(img, (target.cols, target.rows))
        return (np.arange(len(c)), c.reshape(-1, 2)) if ok else None

    run_acquisition(cell.robot, cell.cameras, cell.trajectory, tmp_path / "ds", cell.target, detector=detector,
                    progress=False)
    out = export_mchec(tmp_path / "ds", tmp_path / "mc")
    images = sorted((out / "camera1" / "image").iterdir())
    bad = images[len(images) // 2]
    bad.write_bytes(bad.read_bytes()[:200])
    proc = subprocess.run([sys.executable, "-m", "calibgraph", "solve", str(out), "--out", str(tmp_path / "r.json"),
                           "--quiet"], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "camera1/image/" + bad.name in proc.stderr and "Traceback" not in proc.stderr, proc.stderr[-2000:]
    assert (tmp_path / "r.json").is_file()
