"""Errors a user can cause: each names the file (or option) and says what is wrong."""

from __future__ import annotations


class UserError(ValueError):
    """Bad input from the user: the CLI prints it as one line and exits with code 2."""

    def __init__(self, where, what):
        super().__init__(f"{where}: {what}" if where else str(what))
        self.where, self.what = where, what


def require_extra(extra: str, *modules: str, what: str | None = None) -> None:
    """Raise :class:`UserError` naming ``pip install 'posturemap[extra]'`` (and the editable
    install of a checkout) unless every module
    of ``modules`` can be imported (looked up, not imported: cheap).

    ``what`` names the command or option that needs them (default: the extra).
    """
    import importlib.util

    missing = [m for m in modules if importlib.util.find_spec(m) is None]
    if missing:
        raise UserError(what or extra, f"needs {', '.join(missing)}: pip install 'posturemap[{extra}]' "
                                       f"(in a checkout: pip install -e '.[{extra}]')")
