"""The project's error types, importable from every layer.

``UserInputError`` is the user's mistake (a bad flag, scenario field, parameter or file): the
``ballchain`` command reports it as one line naming the field, the value and what is allowed,
with exit status 2. Anything else that escapes is a bug and stays a traceback.
"""

from __future__ import annotations


class UserInputError(ValueError):
    """Bad input from the user: reported as one line, exit status 2.

    The message names the field (flag, scenario key or parameter), the value and what is allowed.
    """
