"""Thin wrapper: the paper reproduction is `pe-mjx reproduce` (pe_mjx/reproduce.py)."""

import sys

from pe_mjx.cli import main

if __name__ == "__main__":
    main(["reproduce", *sys.argv[1:]])
