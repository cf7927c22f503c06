"""Package layout (the rest of the metadata is in pyproject.toml).

The top-level ``drivers/`` folder is installed as the package ``calibgraph_drivers`` (never as a
generic ``drivers``), for ``pip install .`` and ``pip install -e .`` alike; every subpackage of
``calibgraph`` is found here, so a new one needs no entry.

The shipped files of ``datasets/`` (target specs, workcells, tolerances) are package data: a wheel
carries them as ``calibgraph/datasets/<folder>/*.yaml``, and ``calibgraph.io.shipped`` finds them
there (or in the clone's ``datasets/`` for an editable install), from any folder.
"""

from setuptools import find_packages, setup

SHIPPED = ("targets", "workcells", "tolerances")

setup(packages=find_packages(include=["calibgraph", "calibgraph.*"]) + ["calibgraph_drivers", "calibgraph.datasets"],
      package_dir={"calibgraph_drivers": "drivers", "calibgraph.datasets": "datasets"},
      package_data={"calibgraph.datasets": [f"{d}/*.yaml" for d in SHIPPED]})
