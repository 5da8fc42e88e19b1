"""Ray plumbing shared by ``make-dataset --engine ray`` and ``sweep --engine ray``.

Ray is an optional dependency (``pip install 'doabench[ray]'``). :func:`require_ray` turns its
absence into a one-line :class:`~doabench.errors.DependencyError` (exit code 2 on the command
line). :func:`ray_session` connects to a running cluster (``address``, e.g. ``ray://head:10001``
or ``auto``) or starts a local instance with ``workers`` CPUs, and shuts down only what it
started: a session that finds Ray already initialised (a test fixture, a notebook) reuses it.
"""
from __future__ import annotations

import contextlib
from typing import Any, Iterator, TypeVar

from doabench.errors import ConfigError, DependencyError, DoabenchError

ENGINES = ("local", "ray")


def check_engine(engine: str) -> str:
    if engine not in ENGINES:
        raise ConfigError(f"unknown engine {engine!r}; choose from {', '.join(ENGINES)}")
    return engine


def require_ray() -> Any:
    """The ``ray`` module, or a one-line error saying how to install it."""
    try:
        import ray
    except ImportError:
        raise DependencyError("--engine ray needs Ray, which is not installed; install it with "
                              "pip install 'doabench[ray]'") from None
    return ray


@contextlib.contextmanager
def ray_session(address: str | None = None, workers: int | None = None) -> Iterator[Any]:
    """``ray`` connected to ``address`` or to a new local instance with ``workers`` CPUs."""
    ray = require_ray()
    if ray.is_initialized():
        yield ray
        return
    kwargs: dict[str, Any] = {"include_dashboard": False}
    if address:
        kwargs["address"] = address
    else:
        kwargs.update(address="local", num_cpus=max(1, int(workers or 1)))
    try:
        ray.init(**kwargs)
    except Exception as exc:  # ConnectionError, RuntimeError, ...: one line, not a Ray traceback
        where = f"the Ray cluster at {address}" if address else "a local Ray instance"
        raise DependencyError(f"could not start or reach {where}: {str(exc).splitlines()[0] if str(exc) else exc!r}"
                              ) from None
    try:
        yield ray
    finally:
        ray.shutdown()


def cluster_cpus(ray: Any) -> int:
    """CPUs the connected cluster offers (at least 1)."""
    try:
        return max(1, int(ray.cluster_resources().get("CPU", 1)))
    except Exception:
        return 1


ExceptionT = TypeVar("ExceptionT", bound=BaseException)


def unwrap(exc: ExceptionT) -> ExceptionT | DoabenchError:
    """The user-facing error inside a Ray task error (its ``cause``), else ``exc`` itself."""
    cause = getattr(exc, "cause", None)
    if isinstance(cause, DoabenchError):
        return cause
    return exc
