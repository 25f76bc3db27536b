"""Subcommands of the ``mlx-tempcomp`` command line, one module each."""
