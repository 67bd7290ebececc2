"""The ``fruitnerfpp`` command line: one module per subcommand group."""
