"""Package discovery, the one thing pyproject.toml cannot declare here.

Every package under smol_dsl/ is found automatically (a new subpackage needs no edit here),
and the schedule library is added as `smol_dsl.schedules`: it lives in the checkout's
top-level schedules/ folder, mapped by `[tool.setuptools.package-dir]` in pyproject.toml,
where `[tool.setuptools.packages.find]` cannot reach it. Everything else is in pyproject.toml.
"""

from setuptools import find_packages, setup

setup(packages=[*find_packages(include=["smol_dsl", "smol_dsl.*"]), "smol_dsl.schedules"])
