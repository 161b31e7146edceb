"""The package version: the single source read by ``pyproject.toml`` and ``quadslam --version``."""

__version__ = "0.2.0"
