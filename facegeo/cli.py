"""The ``facegeo`` console command's entry point (pyproject: ``facegeo = "facegeo.cli:main"``;
also ``python -m facegeo.cli``). The commands, their parser and :func:`main` live in
:mod:`facegeo.commands`."""

from __future__ import annotations

import sys

from facegeo.commands import build_parser, main

__all__ = ["main", "build_parser"]

if __name__ == "__main__":
    sys.exit(main())
