"""User-facing errors: the CLI prints one line and exits with status 2."""


class UserError(Exception):
    """Bad input from the user (unknown name, malformed file, unwritable path, ...)."""


def one_line(text: object) -> str:
    """``str(text)`` safe to print as one terminal line: every non-printable character (ANSI escape
    sequences' ESC, carriage return, newline, bidi overrides, lone surrogates of an undecodable file
    name) is written as Python's repr writes it (``\\x1b``, ``\\r``, ``\\n``, ``\\u202e``), so a file
    name or a value from outside cannot colour, rewrite or add lines to the terminal."""
    return "".join(ch if ch.isprintable() else repr(ch)[1:-1] for ch in str(text))
