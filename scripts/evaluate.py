"""Evaluate filtered against unfiltered policies (same as ``safe-nav evaluate``)."""

from __future__ import annotations

import sys

from agents.cli.main import main

if __name__ == "__main__":
    sys.exit(main(["evaluate", *sys.argv[1:]]))
