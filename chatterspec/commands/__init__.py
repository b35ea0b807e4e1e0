"""Subcommands of the ``chatterspec`` CLI (one module each, see :mod:`chatterspec.cli`)."""
