"""One BLAS thread inside illumon's solvers.

The solvers work on many small matrices (tens to a few thousand rows). Multi-threaded BLAS gains nothing there, and
when several processes or service threads run at once, busy-waiting BLAS threads oversubscribe the cores: a joint
retrieval that takes 4 s alone was measured at 60 s next to three other solver processes on a 2-core machine. Entry
points are wrapped with :func:`single_blas_thread` (threadpoolctl; a no-op if it is not installed), which restores the
caller's setting afterwards.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import Any, TypeVar

F = TypeVar("F", bound=Callable[..., Any])

__all__ = ["single_blas_thread", "limit_blas_threads", "blas_threads"]

_controller: Any = None
_blas_libs: list[Any] = []


def _get_controller() -> Any:
    global _controller
    if _controller is None:
        try:
            from threadpoolctl import ThreadpoolController
        except ImportError:  # pragma: no cover - threadpoolctl is a dependency
            _controller = False
        else:
            _controller = ThreadpoolController()
            _blas_libs[:] = _controller.select(user_api="blas").lib_controllers
    return _controller


def _limit() -> Any:
    controller = _get_controller()
    if controller is False or all(lib.num_threads == 1 for lib in _blas_libs):
        # already one thread (the service and refit processes limit the whole process): nothing to limit or restore
        # (threadpoolctl's limit and restore cost ~0.1 ms of a new frame's ~2 ms estimate; issue 29)
        return None
    return controller.limit(limits=1, user_api="blas")


def blas_threads() -> tuple[int, ...]:
    """The threads each BLAS library loaded in this process uses now (threadpoolctl; empty without it): a matrix
    product's sums are split over them, so its last bits depend on their number."""
    controller = _get_controller()
    if controller is False:
        return ()
    return tuple(int(lib.num_threads) for lib in _blas_libs)


def single_blas_thread(func: F) -> F:
    """Run ``func`` with BLAS limited to one thread (about 10 µs per call; ~1 µs when it runs one already)."""

    @functools.wraps(func)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        limiter = _limit()
        if limiter is None:
            return func(*args, **kwargs)
        with limiter:
            return func(*args, **kwargs)

    return wrapper  # type: ignore[return-value]


def limit_blas_threads() -> None:
    """One BLAS/OpenMP thread for the rest of this process (service workers and refit processes; threadpoolctl, a
    no-op if it is not installed): from request threads and the refit thread side by side, BLAS threading gains
    nothing and on a busy machine costs orders of magnitude (an SVD of the identifiability check: 0.02 s with one
    thread, 4 s with two threads competing with other work on two cores)."""
    try:
        from threadpoolctl import threadpool_limits
    except ImportError:  # pragma: no cover - threadpoolctl is a dependency
        return
    threadpool_limits(limits=1)
