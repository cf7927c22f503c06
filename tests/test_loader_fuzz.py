"""Property test (issue 16): random, well-formed-looking dataset, result and trajectory files fed to
the loaders produce a dataset or one clear :class:`CalibgraphError`, never another exception."""

import json
import math
import os
import tempfile
from pathlib import Path

import pytest
import yaml

if os.environ.get("CI"):
    import hypothesis  # noqa: F401  (CI installs the test extra: a missing hypothesis is a failure there)
hypothesis = pytest.importorskip("hypothesis", reason="hypothesis is not installed (pip install -e '.[test]')")
from hypothesis import HealthCheck, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

from calibgraph.core.errors import CalibgraphError  # noqa: E402
from calibgraph.io.layouts import load_dataset  # noqa: E402
from calibgraph.plan.trajectory import load_trajectory  # noqa: E402
from calibgraph.solver.output.result import load_result  # noqa: E402

SETTINGS = settings(max_examples=400, deadline=None, suppress_health_check=[HealthCheck.too_slow])

num = st.one_of(st.floats(-2.0, 2.0), st.floats(allow_nan=True, allow_infinity=True), st.integers(-3, 2000),
                st.just(0.0))
maybe = lambda s: st.one_of(s, st.none(), st.text(max_size=4), st.lists(num, max_size=3))  # noqa: E731


def matrix(n, m):
    good = st.lists(st.lists(st.floats(-2.0, 2.0), min_size=m, max_size=m), min_size=n, max_size=n)
    return st.one_of(good, st.lists(st.lists(num, max_size=m + 1), max_size=n + 1), maybe(num))


def pose():
    """A flange pose: exact identity-like, slightly off, random or malformed."""
    ident = [[1.0, 0, 0, 0.4], [0, 1.0, 0, 0.1], [0, 0, 1.0, 0.5], [0, 0, 0, 1.0]]
    return st.one_of(st.just(ident), matrix(4, 4), st.just([[1.0, 0, 0, 400.0], [0, 1, 0, 0], [0, 0, 1, 500.0],
                                                             [0, 0, 0, 1]]))


target = st.fixed_dictionaries({
    "kind": st.one_of(st.sampled_from(["checkerboard", "charuco", "circles", "asymmetric_circles"]), st.text(max_size=5)),
    "rows": maybe(st.integers(-2, 12)), "cols": maybe(st.integers(-2, 12)), "pitch_m": maybe(num),
})
camera = st.fixed_dictionaries({
    "K": st.one_of(st.just([[900.0, 0, 320], [0, 900.0, 240], [0, 0, 1]]), matrix(3, 3)),
    "dist": st.one_of(st.lists(st.floats(-0.5, 0.5), max_size=9), maybe(num)),
    "width_px": maybe(st.integers(-5, 5000)), "height_px": maybe(st.integers(-5, 5000)),
})
header = st.fixed_dictionaries(
    {"target": st.one_of(target, maybe(num)), "cameras": st.one_of(st.dictionaries(st.sampled_from(["a", "b"]), camera,
                                                                                    max_size=2), maybe(num))},
    optional={"format": st.sampled_from(["calibgraph-dataset/1", "calibgraph-dataset/2", "x"]),
              "mode": st.one_of(st.sampled_from(["eye_to_hand", "eye_in_hand"]), st.text(max_size=4)),
              "solver": st.one_of(st.dictionaries(st.sampled_from(["loss", "pixel_sigma_px", "bogus"]), num, max_size=2),
                                  maybe(num))})
detection = st.fixed_dictionaries({"ids": st.one_of(st.lists(st.integers(-2, 60), max_size=12), maybe(num)),
                                   "uv_px": st.one_of(st.lists(st.lists(num, min_size=2, max_size=2), max_size=12),
                                                      maybe(num))})
view = st.one_of(st.fixed_dictionaries({}, optional={"image": st.one_of(st.text(max_size=6), st.none(), num),
                                                     "detection": st.one_of(detection, st.none(), num)}), maybe(num))
capture = st.fixed_dictionaries(
    {"index": st.one_of(st.integers(-1, 5), st.text(max_size=3), st.none()), "T_base_flange": pose()},
    optional={"q_rad": st.one_of(st.lists(num, max_size=7), st.none()),
              "views": st.one_of(st.dictionaries(st.sampled_from(["a", "b", "c"]), view, max_size=3), maybe(num))})




@SETTINGS
@given(head=header, caps=st.lists(st.one_of(capture, maybe(num)), max_size=5), raw=st.booleans())
def test_dataset_loader_says_what_is_wrong_or_loads(head, caps, raw):
    with tempfile.TemporaryDirectory() as d:
        root = Path(d)
        (root / "dataset.yaml").write_text(yaml.safe_dump(head) if not raw else json.dumps(head)[: len(json.dumps(head)) // 2])
        (root / "captures").mkdir()
        for k, c in enumerate(caps):
            (root / "captures" / f"{k:06d}.json").write_text(json.dumps(c))
        try:
            ds = load_dataset(root)
        except CalibgraphError as e:
            assert str(e) and "\n" not in str(e).strip()  # one line, not empty
            return
        assert len(ds.captures) >= 1


result_camera = st.fixed_dictionaries({}, optional={
    "T_base_cam": matrix(4, 4), "T_flange_cam": matrix(4, 4), "T_ref_cam": matrix(4, 4), "covariance": matrix(6, 6),
    "views_used": maybe(num), "views_rejected": st.one_of(st.lists(st.fixed_dictionaries(
        {"capture": maybe(num)}, optional={"reason": maybe(num)}), max_size=2), maybe(num)),
    "intrinsics": st.one_of(camera, maybe(num)), "reprojection_rms_px": maybe(num)})
result = st.fixed_dictionaries({"cameras": st.one_of(st.dictionaries(st.text(max_size=3), st.one_of(
    result_camera, maybe(num)), max_size=2), maybe(num)),
    "mode": st.one_of(st.sampled_from(["eye_to_hand", "eye_in_hand"]), maybe(num))},
    optional={"format": st.one_of(st.sampled_from(["calibgraph-result/1", "calibgraph-result/3"]), st.text(max_size=4)),
              "solver": st.one_of(st.fixed_dictionaries({}, optional={"converged": maybe(st.booleans()),
                                                                      "iterations": maybe(num),
                                                                      "settings": maybe(num)}), maybe(num)),
              "T_flange_board": matrix(4, 4), "board_scale": st.one_of(st.fixed_dictionaries(
                  {"scale": maybe(num), "sigma": maybe(num)}), maybe(num)),
              "notes": st.one_of(st.lists(st.text(max_size=4), max_size=2), maybe(num)),
              "rejected_corners": st.one_of(st.lists(st.fixed_dictionaries(
                  {"camera": maybe(num), "capture": maybe(num), "id": maybe(num), "residual_px": maybe(num)}),
                  max_size=2), maybe(num)),
              "residuals": st.one_of(st.dictionaries(st.text(max_size=3), st.dictionaries(
                  st.one_of(st.text(max_size=2), st.just("0")), st.fixed_dictionaries(
                      {"ids": maybe(num), "uv_detected_px": matrix(2, 2), "residual_px": matrix(2, 2)},
                      optional={"weight": maybe(num), "rejected": maybe(st.booleans())}), max_size=2),
                  max_size=2), maybe(num))})


@SETTINGS
@given(res=st.one_of(result, maybe(num)), yaml_ext=st.booleans())
def test_result_loader_says_what_is_wrong_or_loads(res, yaml_ext):
    with tempfile.TemporaryDirectory() as d:
        p = Path(d) / ("r.yaml" if yaml_ext else "r.json")
        p.write_text(yaml.safe_dump(res) if yaml_ext else json.dumps(res))
        try:
            load_result(p)
        except CalibgraphError as e:
            assert str(e) and "\n" not in str(e).strip()


traj = st.fixed_dictionaries({"poses": st.one_of(st.lists(st.one_of(
    st.fixed_dictionaries({"q_rad": st.one_of(st.lists(num, max_size=8), maybe(num))},
                          optional={"T_base_flange": pose(), "capture": st.one_of(st.booleans(), num),
                                    "cameras": st.one_of(st.lists(st.text(max_size=3), max_size=2), num)}),
    st.lists(num, max_size=8)), max_size=4), maybe(num))},
    optional={"format": st.sampled_from(["calibgraph-trajectory/1", "calibgraph-trajectory/5"]),
              "speed_scale": maybe(num)})


@SETTINGS
@given(t=st.one_of(traj, maybe(num)))
def test_trajectory_loader_says_what_is_wrong_or_loads(t):
    with tempfile.TemporaryDirectory() as d:
        p = Path(d) / "t.yaml"
        p.write_text(yaml.safe_dump(t))
        try:
            load_trajectory(p)
        except CalibgraphError as e:
            assert str(e)




_REAL_RESULT = []


def _real_result() -> dict:
    """A real result file's content (a small synthetic solve), made once."""
    if not _REAL_RESULT:
        from calibgraph import solve
        from calibgraph.sim.synthetic_corners import make_scene

        d = json.loads(json.dumps(solve(make_scene(n_poses=10, seed=3).problem).to_dict()))
        for name, per in d["residuals"].items():  # two views per camera keep every kind of entry and the file small
            d["residuals"][name] = dict(list(per.items())[:2])
        d["robot_flange_poses_refined"] = dict(list(d["robot_flange_poses_refined"].items())[:3])
        _REAL_RESULT.append(d)
    return _REAL_RESULT[0]


def _leaves(d, path=()):
    """Every (path, container) in a JSON document, leaves and branches alike."""
    out = [path]
    items = d.items() if isinstance(d, dict) else enumerate(d) if isinstance(d, list) else ()
    for k, v in items:
        out += _leaves(v, path + (k,))
    return out


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(data=st.data(), yaml_ext=st.integers(0, 4).map(lambda k: k == 0))
def test_a_real_result_with_one_entry_replaced_loads_or_says_what_is_wrong(data, yaml_ext):
    d = json.loads(json.dumps(_real_result()))
    paths = _leaves(d)[1:]
    for _ in range(data.draw(st.integers(1, 3))):
        path = data.draw(st.sampled_from(paths))
        parent = d
        try:
            for k in path[:-1]:
                parent = parent[k]
            value = data.draw(st.one_of(maybe(num), st.dictionaries(st.text(max_size=2), num, max_size=2),
                                        st.just(None), st.just(object)))
            if value is object:
                del parent[path[-1]]
            else:
                parent[path[-1]] = value
        except (KeyError, IndexError, TypeError):
            continue  # an earlier replacement removed this path
    with tempfile.TemporaryDirectory() as tmp:
        p = Path(tmp) / ("r.yaml" if yaml_ext else "r.json")
        p.write_text(yaml.dump(d, Dumper=getattr(yaml, "CSafeDumper", yaml.SafeDumper)) if yaml_ext else json.dumps(d))
        try:
            load_result(p)
        except CalibgraphError as e:
            assert str(e) and "\n" not in str(e).strip()
