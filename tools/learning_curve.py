"""Thin wrapper: learning curves are `pe-mjx plot RUN` (pe_mjx/plots.py)."""

import sys

from pe_mjx.cli import main

if __name__ == "__main__":
    main(["plot", *sys.argv[1:]])
