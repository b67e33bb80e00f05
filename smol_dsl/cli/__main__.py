"""`python -m smol_dsl.cli`: the `smol-dsl` command."""

import sys

from smol_dsl.cli import main

if __name__ == "__main__":
    sys.exit(main())
