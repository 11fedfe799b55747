"""The ``sensorless`` command line: one module per subcommand, each reaching families through their hooks."""
