"""Subcommands of the ``pointviz`` CLI; see :mod:`pointviz.cli`."""
