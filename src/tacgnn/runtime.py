"""Process-wide settings an entry point (CLI, benchmark, training script) may opt into.

Nothing here runs on import: each setting changes the whole process, so only the
program's entry point should choose it.
"""

from __future__ import annotations


def keep_freed_memory(mmap_threshold: int = 32 << 20, trim_threshold: int = 256 << 20) -> bool:
    """Opt-in, glibc only: let ``malloc`` keep freed memory for reuse.

    Why: a forward pass allocates and frees MBs of temporaries. With glibc's default
    settings, freed heap can be returned to the OS and page-faulted back in on the next
    call (this cost TacGNN ~40% of its CPU time before its edge work was chunked; now a
    few %). Same as setting the environment variables ``MALLOC_MMAP_THRESHOLD_`` and
    ``MALLOC_TRIM_THRESHOLD_``; the process then keeps up to ``trim_threshold`` bytes of
    free heap. Returns False where it does not apply.
    """
    import ctypes

    try:
        libc = ctypes.CDLL("libc.so.6")
        M_TRIM_THRESHOLD, M_MMAP_THRESHOLD = -1, -3  # from <malloc.h>
        return bool(libc.mallopt(M_MMAP_THRESHOLD, mmap_threshold)) and bool(
            libc.mallopt(M_TRIM_THRESHOLD, trim_threshold)
        )
    except (OSError, AttributeError):
        return False
