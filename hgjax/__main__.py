"""The ``hgjax`` console script and ``python -m hgjax``: :func:`console`."""

from hgjax.cli import exit_on_signals


def console() -> None:
    """Run :func:`hgjax.cli.main` as the ``hgjax`` command, with SIGINT and SIGTERM ending the run
    at once (:func:`hgjax.cli.exit_on_signals`) from before the parser (:mod:`hgjax.cli._main`) is imported;
    :func:`hgjax.cli.main` then installs its own handlers in their place."""
    exit_on_signals()
    from hgjax.cli import main

    main()


if __name__ == "__main__":
    console()
