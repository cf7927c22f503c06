"""Solver options are declared once (``SolverOptions``, each flag on its field): every option is
reachable from a flag of ``calibgraph solve`` or from dataset.yaml's solver section, every flag keeps
its name and meaning and its value reaches the options the solver is given, and a flag that cannot
take effect is refused in one line, never ignored."""

from __future__ import annotations

import json
from dataclasses import fields
from functools import lru_cache

import numpy as np
import pytest
import yaml
from helpers import write_sim_dataset

import calibgraph.cli.solve as cli_solve
from calibgraph.cli.main import main
from calibgraph.core.problem import SolverOptions, option_flags
from calibgraph.sim.kinematic_scene import make_kinematic_scene

# The public flags of `calibgraph solve` and what each sets (scripts outside the repository use them):
# flag -> (value given, option, option value). A flag added to or dropped from SolverOptions must be
# added here too: this table is the interface.
FLAGS = {
    "--pixel-sigma": ("0.37", "pixel_sigma_px", 0.37),
    "--fk-sigma-mm": ("0.2", "fk_sigma_translation_m", 2e-4),
    "--fk-sigma-deg": ("0.02", "fk_sigma_rotation_rad", np.radians(0.02)),
    "--loss": ("cauchy", "loss", "cauchy"),
    "--refine-intrinsics": (None, "intrinsics", "estimate"),
    "--fixed-intrinsics": (None, "intrinsics", "fixed"),
    "--intrinsics-source": ("factory", "intrinsics_source", "factory"),
    "--fixed-board-scale": (None, "board_scale", False),
    "--estimate-kinematics": ("joint-offsets", "kinematics", "joint-offsets"),
    "--kinematic-model": ("my_arm.urdf", "kinematics_model", "my_arm.urdf"),
    "--kinematics-staging": ("staged", "kinematics_staging", "staged"),
}

# a valid value other than the default for every option, as dataset.yaml's solver section gives it
SOLVER_SECTION = {
    "fk_sigma_translation_m": 3e-4, "fk_sigma_rotation_rad": 4e-4, "pixel_sigma_px": 0.25, "loss": "none",
    "loss_scale": 3.0, "outlier_sigmas": 6.0, "min_views_per_camera": 4, "max_iterations": 50, "intrinsics": "fixed",
    "intrinsics_source": "exact", "refine_intrinsics": True, "intrinsics_sigma_px": 7.0, "distortion_sigma": 0.2,
    "board_scale": False, "board_scale_sigma": 0.01, "formulation": "view", "kinematics": "joint-offsets",
    "kinematics_model": "franka_custom.urdf", "joint_offset_prior_rad": 0.02, "kinematics_staging": "staged",
    "view_noise_modes": False, "fk_variance": False, "corner_noise": "per-camera", "fk_repeat_translation_m": 5e-5,
    "fk_repeat_rotation_rad": 1e-4,
}


@lru_cache(maxsize=1)
def _problem():
    sc, _ = make_kinematic_scene(n_poses=20, seed=2)  # carries q_rad, which --estimate-kinematics needs
    return sc.problem


def _dataset(root, solver=None):
    write_sim_dataset(root, _problem())
    if solver:
        head = yaml.safe_load((root / "dataset.yaml").read_text())
        head["solver"] = solver
        (root / "dataset.yaml").write_text(yaml.safe_dump(head))
    return root


class _Given(Exception):
    """Raised in place of solving, carrying the problem the solver would have been given."""


def _options_given(monkeypatch, argv) -> SolverOptions:
    """The options of the problem `calibgraph solve ARGV` hands to the solver (stopped there)."""
    real = cli_solve.build_problem

    def build_and_stop(*a, **kw):
        problem, _ = real(*a, **kw)
        raise _Given(problem)

    monkeypatch.setattr(cli_solve, "build_problem", build_and_stop)
    with pytest.raises(_Given) as e:
        main([str(a) for a in argv])
    return e.value.args[0].options


def test_the_tables_cover_every_option_and_every_flag():
    names = [f.name for f in fields(SolverOptions)]
    assert sorted(SOLVER_SECTION) == sorted(names)
    declared = {flag.name for flag in option_flags().values()}
    assert declared == set(FLAGS)
    assert all(getattr(SolverOptions(), n) != v for n, v in SOLVER_SECTION.items())
    assert all(f.metadata.get("flag") is None or f.metadata["flag"].help for f in fields(SolverOptions))


@pytest.mark.parametrize("name", sorted(SOLVER_SECTION))
def test_every_option_reaches_the_solver_from_dataset_yaml(name, tmp_path, monkeypatch):
    ds = _dataset(tmp_path / "ds", {name: SOLVER_SECTION[name]})
    opts = _options_given(monkeypatch, ["solve", ds, "--quiet"])
    assert getattr(opts, name) == SOLVER_SECTION[name]


@pytest.mark.parametrize("flag", sorted(FLAGS))
def test_every_flag_reaches_the_solver(flag, tmp_path, monkeypatch):
    value, name, want = FLAGS[flag]
    ds = _dataset(tmp_path / "ds")
    opts = _options_given(monkeypatch, ["solve", ds, "--quiet", flag] + ([value] if value is not None else []))
    got = getattr(opts, name)
    assert got == pytest.approx(want, rel=1e-12) if isinstance(want, float) else got == want
    # and the rest stay at their defaults
    for f in fields(SolverOptions):
        if f.name != name and not (flag == "--refine-intrinsics" and f.name == "refine_intrinsics"):
            assert getattr(opts, f.name) == getattr(SolverOptions(), f.name), f.name


def test_flags_win_over_dataset_yaml(tmp_path, monkeypatch):
    ds = _dataset(tmp_path / "ds", {"pixel_sigma_px": 0.25, "loss": "none", "fk_sigma_translation_m": 3e-4})
    opts = _options_given(monkeypatch, ["solve", ds, "--quiet", "--pixel-sigma", "0.5", "--loss", "huber"])
    assert (opts.pixel_sigma_px, opts.loss, opts.fk_sigma_translation_m) == (0.5, "huber", 3e-4)


@pytest.mark.parametrize("argv, says", [
    (["--pixel-sigma", "0"], "--pixel-sigma 0: must be a positive number"),
    (["--fk-sigma-mm", "0"], "--fk-sigma-mm 0: must be a positive number"),
    (["--fk-sigma-deg", "0"], "--fk-sigma-deg 0: must be a positive number"),
    (["--pixel-sigma", "-0.3"], "--pixel-sigma -0.3: must be a positive number"),
    (["--fk-sigma-mm", "inf"], "--fk-sigma-mm inf: must be a positive number"),
    (["--refine-intrinsics", "--fixed-intrinsics"], "--fixed-intrinsics and --refine-intrinsics contradict each other"),
])
def test_a_flag_that_cannot_take_effect_is_refused_in_one_line(argv, says, tmp_path, capsys):
    ds = _dataset(tmp_path / "ds")
    assert main(["solve", str(ds), "--out", str(tmp_path / "r.json"), *argv]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and says in err[0], err
    assert not (tmp_path / "r.json").exists()


def test_a_flag_contradicting_dataset_yaml_is_refused(tmp_path, capsys):
    ds = _dataset(tmp_path / "ds", {"refine_intrinsics": True})
    assert main(["solve", str(ds), "--fixed-intrinsics", "--quiet"]) == 2
    assert "--fixed-intrinsics and dataset.yaml's solver section contradict" in capsys.readouterr().err


def test_solved_result_records_the_flags_values(tmp_path):
    """End to end: the settings the solver records in result.json are the flags' values in SI units."""
    ds = _dataset(tmp_path / "ds")
    out = tmp_path / "r.json"
    assert main(["solve", str(ds), "--out", str(out), "--quiet", "--pixel-sigma", "0.4", "--fk-sigma-mm", "0.2",
                 "--fk-sigma-deg", "0.02", "--loss", "cauchy", "--fixed-board-scale"]) == 0
    s = json.loads(out.read_text())["solver"]["settings"]
    assert (s["pixel_sigma_px"], s["fk_sigma_translation_m"], s["loss"], s["board_scale"]) == (0.4, 2e-4, "cauchy", False)
    assert s["fk_sigma_rotation_rad"] == pytest.approx(np.radians(0.02), rel=1e-12)
