"""The error a user's mistake raises: the command line prints it as one line and exits 2."""

from __future__ import annotations


class InputError(ValueError):
    """Bad input from the user: a file, a line, a field or an option that is not what we expect.

    The message names the place (file, line, key) and what was expected; it is shown to the
    user as is, without a traceback, on one line: line breaks in it (a YAML parser's or a bag
    reader's own message quoted in it) become spaces.
    """

    def __init__(self, message: object = "") -> None:
        super().__init__(" ".join(str(message).split()))
