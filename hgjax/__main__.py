"""The ``hgjax`` console script and ``python -m hgjax``: :func:`console`."""

from hgjax._cli_signals import exit_on_signals


def console() -> None:
    """Run :func:`hgjax.cli.main` as the ``hgjax`` command, with SIGINT and SIGTERM ending the run
    at once (:func:`hgjax._cli_signals.exit_on_signals`) from before :mod:`hgjax.cli` is imported;
    :func:`hgjax.cli.main` then installs its own handlers in their place."""
    exit_on_signals()
    from hgjax.cli import main

    main()


if __name__ == "__main__":
    console()
