"""The package version, in a module of its own so that no module imports the package root
(``doabench/__init__.py``, which loads the task registry and re-exports the public API) for it.
Keep it equal to ``[project] version`` in pyproject.toml (tests/test_architecture.py checks)."""

__version__ = "0.1.0"
