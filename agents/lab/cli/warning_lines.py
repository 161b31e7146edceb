"""How the ``quadslam`` command shows this package's warnings: one line, like its errors.

A warning raised in this package (a run folder without a manifest, an evaluation on another
setup than training) prints as ``quadslam evaluate: warning: …`` instead of Python's two
lines with a file, a line number and a source line; warnings of other libraries keep
Python's format.
"""

from __future__ import annotations

import contextlib
import os
import warnings
from collections.abc import Iterator


@contextlib.contextmanager
def one_line_warnings(command: str) -> Iterator[None]:
    """Inside the block, warnings raised in the ``agents`` package print as one line.

    Args:
        command: The subcommand, for the line's prefix (``quadslam <command>: warning:``).
    """
    import agents

    home = os.path.dirname(os.path.abspath(agents.__file__)) + os.sep
    default = warnings.formatwarning

    def one_line(
        message: Warning | str,
        category: type[Warning],
        filename: str,
        lineno: int,
        line: str | None = None,
    ) -> str:
        if os.path.abspath(filename).startswith(home):
            return f"quadslam {command}: warning: {' '.join(str(message).split())}\n"
        return default(message, category, filename, lineno, line)

    warnings.formatwarning = one_line
    try:
        yield
    finally:
        warnings.formatwarning = default
