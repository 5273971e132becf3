"""Atomic file writes: a file is either absent or complete, never half-written.

One implementation, in the lowest layer (:mod:`overtakezoo.envs.io`, so the zoo's trainers can use
it too), re-exported here for the benchmark. The CLI reports a :class:`WriteError` as one
``error:`` line, like a :class:`~overtakezoo.benchmark.errors.UserError`.
"""

from overtakezoo.envs.io import (WriteError, atomic_directory, atomic_output, atomic_path, atomic_write_bytes,
                                 atomic_write_json, atomic_write_text, check_writable, check_writable_dir,
                                 sweep_stale, temp_directory)

__all__ = ["WriteError", "atomic_output", "atomic_path", "atomic_directory", "atomic_write_bytes",
           "atomic_write_text", "atomic_write_json", "check_writable", "check_writable_dir", "sweep_stale",
           "temp_directory"]
