"""How the model kernels are compiled: numba ``njit(cache=True)``, never ``fastmath``.

``fastmath`` stays off so results are IEEE-reproducible (no reassociation, no fused
multiply–adds): lane i of a batch equals the single env bit for bit, on every machine that
runs the same numba/LLVM.

numba writes its cache next to the module (``__pycache__``), else to ``NUMBA_CACHE_DIR`` or a
per-user cache directory. If none is writable (read-only install, no home directory), numba
refuses ``cache=True`` when the function is decorated, which would make ``import quadslam_env``
fail; the decorators below then compile without a cache (slower first call per process) and
warn once.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable
from typing import Any, TypeVar

from numba import njit, vectorize

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
            stacklevel=3,
        )


def kernel(func: F) -> F:
    """``numba.njit(cache=True)`` (falls back to an uncached ``njit`` as explained above)."""
    try:
        return njit(cache=True)(func)
    except RuntimeError as err:
        _uncached(err)
        return njit(func)


def elementwise(signature: str) -> Callable[[F], F]:
    """``numba.vectorize([signature], cache=True)``: a NumPy ufunc from a scalar kernel."""

    def deco(func: F) -> F:
        try:
            return vectorize([signature], cache=True)(func)
        except RuntimeError as err:
            _uncached(err)
            return vectorize([signature])(func)

    return deco
