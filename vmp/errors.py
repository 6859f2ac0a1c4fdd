"""The error a user's mistake raises: the command line prints it as one line and exits 2."""


class InputError(ValueError):
    """Bad input from the user: a file, a line, a field or an option that is not what we expect.

    The message names the place (file, line, key) and what was expected; it is shown to the
    user as is, without a traceback.
    """
