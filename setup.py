"""Package discovery. The three layers sit at the repository root (envs/, zoo/, benchmark/) and install
as ``overtakezoo.envs``, ``overtakezoo.zoo`` and ``overtakezoo.benchmark``. pyproject.toml's
``[tool.setuptools.packages.find]`` finds them, but only under their folder names; it cannot add the
``overtakezoo.`` prefix, so the prefix is added here. Everything else is in pyproject.toml."""

from setuptools import find_packages, setup

LAYERS = ("envs", "zoo", "benchmark")

setup(
    packages=[f"overtakezoo.{p}" for p in find_packages(include=[f"{layer}*" for layer in LAYERS])],
    package_dir={f"overtakezoo.{layer}": layer for layer in LAYERS},
)
