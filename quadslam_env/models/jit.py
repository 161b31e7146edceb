"""How the model kernels are compiled: numba ``njit(cache=True)``, never ``fastmath``.

``fastmath`` stays off so results are IEEE-reproducible (no reassociation, no fused
multiply–adds): lane i of a batch equals the single env bit for bit, on every machine that
runs the same numba/LLVM.

numba writes its cache next to the module (``__pycache__``), else to ``NUMBA_CACHE_DIR`` or a
per-user cache directory. If none is writable (read-only install, no home directory), numba
refuses ``cache=True`` when the function is decorated, which would make ``import quadslam_env``
fail; the decorators below then compile without a cache (slower first call per process) and
warn once.

numba checks a cached kernel against its own module's source file only (modification time and
size), not against the kernels it calls: after editing a kernel that another module's kernel
calls or inlines (e.g. ``models/rotors.py:allocate`` inside
``models/integrators.py:vehicle_step_rotor_lanes``), the caller's cache is stale until its own
file changes. A fresh install writes every file anew, so this only concerns editing a checkout:
``make clean-kernels`` deletes the caches.
"""

from __future__ import annotations

import sys
import warnings
from collections.abc import Callable
from functools import partial
from typing import Any, TypeVar

from numba import guvectorize, njit, vectorize
from numba.core import event

F = TypeVar("F", bound=Callable[..., Any])

_warned = False


def _uncached(err: RuntimeError) -> None:
    """Re-raise ``err`` unless it is numba's "no cache location"; warn about it once."""
    global _warned
    if "cannot cache" not in str(err):
        raise err
    if not _warned:
        _warned = True
        warnings.warn(
            f"numba found no writable cache location ({err}); kernels are compiled in every "
            "process. Set NUMBA_CACHE_DIR to a writable directory to cache them.",
            stacklevel=4,
        )


def _compile(func: F, decorator: Callable[..., Callable[[F], F]]) -> F:
    """``decorator(cache=True)(func)``, else (no cache location) ``decorator()(func)``."""
    try:
        return decorator(cache=True)(func)
    except RuntimeError as err:
        _uncached(err)
        return decorator()(func)


def kernel(func: F) -> F:
    """``numba.njit(cache=True)`` (falls back to an uncached ``njit`` as explained above)."""
    return _compile(func, njit)


def inline_kernel(func: F) -> F:
    """:func:`kernel` inlined into its callers at numba IR level (``inline="always"``).

    For small pieces of a hot kernel that are also called on their own (e.g. a landmark
    EKF's prediction, shared by the update and the data association): a separately compiled
    callee returning nested tuples can cost a fifth of the caller's time, the inlined one
    nothing.
    """
    return _compile(func, _njit_inline)


def _njit_inline(**options: Any) -> Any:
    """``numba.njit(inline="always", **options)``."""
    return njit(inline="always", **options)


def elementwise(signature: str) -> Callable[[Callable[..., Any]], Any]:
    """``numba.vectorize([signature], cache=True)``: a NumPy ufunc from a scalar kernel.

    The result is a ufunc (array in, array out), not a function with the kernel's signature,
    so it is typed ``Any``.
    """
    return partial(_compile, decorator=partial(vectorize, [signature]))


def generalized(signature: str, layout: str) -> Callable[[Callable[..., Any]], Any]:
    """``numba.guvectorize([signature], layout, cache=True)``: a NumPy gufunc from a kernel.

    The kernel works on the core dimensions of ``layout`` (e.g. ``"(n),(n,n),(n)->(n)"``) and
    writes its outputs in place; the gufunc broadcasts every leading axis of its inputs the
    way NumPy operators do and loops over them in compiled code, without copies. Called
    without the output arguments it allocates and returns them, so the result is typed
    ``Any`` (a gufunc), not the kernel's signature.
    """
    return partial(_compile, decorator=partial(guvectorize, [signature], layout))


COMPILE_NOTICE = "compiling kernels (first run only: numba caches them for the next runs)"


class _CompileNotice(event.Listener):
    """Writes :data:`COMPILE_NOTICE` once, at the first compilation in this process."""

    def __init__(self, write: Callable[[str], object]) -> None:
        self.write: Callable[[str], object] | None = write

    def on_start(self, ev: event.Event) -> None:
        if self.write is not None:
            write, self.write = self.write, None
            write(COMPILE_NOTICE)

    def on_end(self, ev: event.Event) -> None:
        """Nothing at the end of a compilation."""


def announce_compilation(write: Callable[[str], object] | None = None) -> None:
    """Say in one line when this process first compiles a kernel (nothing on a warm cache).

    A cold cache costs the first run tens of seconds before the first step; a command-line
    tool calls this so that the wait has a reason on screen.

    Args:
        write: Where the line goes (default: a line on stderr).
    """
    event.register("numba:compile", _CompileNotice(write or _to_stderr))


def _to_stderr(line: str) -> None:
    print(f"quadslam: {line}", file=sys.stderr, flush=True)
