"""The ``railwatch`` command line (:mod:`railwatch.cli.app`)."""

from railwatch.cli.app import cli, main

__all__ = ["cli", "main"]
