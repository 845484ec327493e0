"""Errors a user can cause: each names the file (or option) and says what is wrong."""

from __future__ import annotations


class UserError(ValueError):
    """Bad input from the user: the CLI prints it as one line and exits with code 2."""

    def __init__(self, where, what):
        super().__init__(f"{where}: {what}" if where else str(what))
        self.where, self.what = where, what
