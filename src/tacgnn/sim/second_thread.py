"""A second thread for the env step's own work, which otherwise runs on one core while the other idles.

The physics runs on every core; what the env does around it (the skin, the late-skin ring, the
copy of an observation at a reset) is serial. Work that releases the GIL (numpy's matrix products
and copies, the numba kernels) runs beside the main thread's: `beside(fn, *args)` starts it,
`.result()` waits. Each task reads only what nobody writes meanwhile, writes only its own outputs
and draws from no random stream, so the results are those of the serial order, bit for bit
(`tests/test_second_thread.py` runs the env both ways). `ENABLED = False` runs every task inline.
"""

from __future__ import annotations

from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from typing import Any, TypeVar

T = TypeVar("T")
ENABLED = True
_pool: ThreadPoolExecutor | None = None


def beside(fn: Callable[..., T], *args: Any, inline: bool = False) -> Future[T]:
    """Run `fn(*args)` on the second thread (`inline`, or not `ENABLED`: now, on this one);
    `.result()` gives its value."""
    global _pool
    if inline or not ENABLED:
        done: Future[T] = Future()
        done.set_result(fn(*args))
        return done
    if _pool is None:
        _pool = ThreadPoolExecutor(1, thread_name_prefix="tacgnn-env")
    return _pool.submit(fn, *args)
