"""What pyproject.toml cannot say: the packages are found, and docs/ goes into the wheel as
the package data tmcl_spec/docs (tmcl_spec.package.docs_location finds it there, or the
checkout's docs/ when run from the source tree).  Everything else is in pyproject.toml."""

from setuptools import find_packages, setup

setup(
    packages=[*find_packages(include=["tmcl_server*", "interpreter*", "axes*", "tmcl_spec*"]),
              "tmcl_spec.docs"],
    package_dir={"tmcl_spec.docs": "docs"},
)
