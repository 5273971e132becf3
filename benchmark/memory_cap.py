"""A memory limit around the parse of an outside file (a downloaded policy, archive or dataset).

Size checks before inflating stop the bombs we know of (zip members, MCAP chunks, npz arrays);
this is the backstop for the ones we do not: while the parse runs, the process's address space may
grow by at most ``budget`` bytes (``RLIMIT_AS``, restored after), so a parser that allocates past it
gets a ``MemoryError`` (C++ code: ``std::bad_alloc``) and the command ends with one line instead of
driving the machine into swap. Linux only (elsewhere a no-op: the size checks still hold).
"""

from __future__ import annotations

import contextlib
import resource
from collections.abc import Iterator

from overtakezoo.benchmark.errors import UserError

PARSE_BUDGET = 2 << 30  # bytes an outside file's parse may add to the address space (legit ones: a few MB)


def _address_space() -> int | None:
    """This process's current virtual size in bytes (``VmSize``), or None where /proc has none."""
    try:
        with open("/proc/self/status", "rb") as f:
            for line in f:
                if line.startswith(b"VmSize:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        return None
    return None


def out_of_memory(exc: BaseException) -> bool:
    """Whether ``exc`` is an allocation that failed (a parser's broad ``except`` re-raises these, so the
    cap's one line is what the user sees, not "corrupt file")."""
    if isinstance(exc, MemoryError):
        return True
    text = str(exc).lower()  # torch and onnx re-raise std::bad_alloc as RuntimeError
    return isinstance(exc, RuntimeError) and (
        "bad_alloc" in text or "not enough memory" in text or "failed to allocate" in text
    )


@contextlib.contextmanager
def memory_cap(what: str, budget: int | None = None) -> Iterator[None]:
    """Run the block with at most ``budget`` (default :data:`PARSE_BUDGET`) more bytes of address
    space; a parse that needs more is one :class:`UserError` naming ``what``. Nested caps keep the
    tighter one."""
    budget = PARSE_BUDGET if budget is None else budget
    now = _address_space()
    soft, hard = resource.getrlimit(resource.RLIMIT_AS)
    cap = None if now is None else now + budget
    if cap is not None and hard != resource.RLIM_INFINITY:
        cap = min(cap, hard)
    if cap is not None and soft != resource.RLIM_INFINITY and soft <= cap:
        cap = None  # an outer (or the user's own) limit is already tighter
    if cap is not None:
        resource.setrlimit(resource.RLIMIT_AS, (cap, hard))
    try:
        yield
    except Exception as exc:
        if cap is not None and out_of_memory(exc):
            raise UserError(
                f"{what}: reading it needs more than {budget >> 20} MiB of memory (a compression "
                "bomb, or not what it claims to be)"
            ) from None
        raise
    finally:
        if cap is not None:
            resource.setrlimit(resource.RLIMIT_AS, (soft, hard))
