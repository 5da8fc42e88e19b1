"""Package discovery: every package under doabench/ is found by setuptools (a new one needs no
list to be edited), plus the two folders installed under another name (pyproject.toml's
``package-dir``: baselines/ as ``doabench_baselines``, tasks/ as ``doabench.task_specs``), which
discovery cannot map from their folder names, and the subpackages of baselines/ (``trackers``).
Everything else is in pyproject.toml."""
from setuptools import find_packages, setup

RENAMED_PACKAGES = ["doabench_baselines", "doabench.task_specs"]


def packages(root: str = ".") -> list[str]:
    """The packages to install, found under ``root`` (the project folder)."""
    from pathlib import Path

    baselines = [f"doabench_baselines.{sub}" for sub in find_packages(where=str(Path(root) / "baselines"))]
    return find_packages(where=root, include=["doabench", "doabench.*"]) + RENAMED_PACKAGES + baselines


if __name__ == "__main__":  # as setuptools' build backend runs it
    setup(packages=packages())
