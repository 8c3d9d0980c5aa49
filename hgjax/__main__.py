"""``python -m hgjax``: the same as the ``hgjax`` console script. ``hgjax`` and ``hgjax.cli`` import
nothing heavy, so :func:`hgjax.cli.main` installs its signal handlers before JAX is imported; a
Ctrl-C during the light import itself ends the same way."""

import sys

if __name__ == "__main__":
    try:
        from hgjax.cli import main
    except KeyboardInterrupt:
        print("hgjax: interrupted", file=sys.stderr)
        sys.exit(130)
    sys.exit(main())
