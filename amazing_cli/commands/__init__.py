"""The ``amazing`` command's commands, by what they act on; :mod:`amazing_cli.main` builds the
app from them."""
