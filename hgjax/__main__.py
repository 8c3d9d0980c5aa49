"""``python -m hgjax``: the same as the ``hgjax`` console script."""

import sys

if __name__ == "__main__":
    try:
        from hgjax.cli import main
    except KeyboardInterrupt:
        print("hgjax: interrupted", file=sys.stderr)
        sys.exit(130)
    sys.exit(main())
