"""``python -m hgjax``: the same as the ``hgjax`` console script (:func:`hgjax._cli_signals.console`),
which handles SIGINT and SIGTERM before :mod:`hgjax.cli` is imported."""

if __name__ == "__main__":
    from hgjax._cli_signals import console

    console()
