"""Package discovery: every package under doabench/ is found by setuptools (a new one needs no
list to be edited), plus the two folders installed under another name (pyproject.toml's
``package-dir``: baselines/ as ``doabench_baselines``, tasks/ as ``doabench.task_specs``), which
discovery cannot map from their folder names. Everything else is in pyproject.toml."""
from setuptools import find_packages, setup

RENAMED_PACKAGES = ["doabench_baselines", "doabench.task_specs"]


def packages(root: str = ".") -> list[str]:
    """The packages to install, found under ``root`` (the project folder)."""
    return find_packages(where=root, include=["doabench", "doabench.*"]) + RENAMED_PACKAGES


if __name__ == "__main__":  # as setuptools' build backend runs it
    setup(packages=packages())
