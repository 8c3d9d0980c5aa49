"""``python -m hgjax``: the same as the ``hgjax`` console script."""

import sys

from hgjax.cli import main

if __name__ == "__main__":
    sys.exit(main())
