"""The ``safe-nav`` command line (``train``, ``evaluate``, ``reproduce``, ``bench``)."""

from agents.cli.main import main

__all__ = ["main"]
