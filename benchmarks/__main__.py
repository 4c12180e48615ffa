"""``python -m benchmarks [options]``: the same as ``safe-nav bench [options]``."""

import sys

from agents.cli import main

if __name__ == "__main__":
    sys.exit(main(["bench", *sys.argv[1:]]))
