"""Package layout (the rest of the metadata is in pyproject.toml).

The top-level ``drivers/`` folder is installed as the package ``calibgraph_drivers`` (never as a
generic ``drivers``), for ``pip install .`` and ``pip install -e .`` alike; every subpackage of
``calibgraph`` is found here, so a new one needs no entry.
"""

from setuptools import find_packages, setup

setup(packages=find_packages(include=["calibgraph", "calibgraph.*"]) + ["calibgraph_drivers"],
      package_dir={"calibgraph_drivers": "drivers"})
