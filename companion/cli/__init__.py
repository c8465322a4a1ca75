"""The `uavsearch` command line: the top layer, one module per group of commands."""
