"""One module per CLI command (see cosim/cli.py)."""
