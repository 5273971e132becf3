"""User-facing errors: the CLI prints one line and exits with status 2."""


class UserError(Exception):
    """Bad input from the user (unknown name, malformed file, unwritable path, ...)."""
