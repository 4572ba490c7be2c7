"""The one exception type a user ever sees, and how it is shown.

Every check that rejects user input raises :class:`BpsflowError` with a message
that names the file, the key path (or IDF object and field) and what was
expected. The CLI prints the message as one paragraph and exits non-zero; no
traceback reaches the user.
"""

from __future__ import annotations

from pathlib import Path


class BpsflowError(Exception):
    """A user-facing error: bad input, a missing file, a failed engine run.

    Parameters
    ----------
    message : str
        One paragraph: what was wrong, where (file, key path), what was expected.
    source : str or Path, optional
        The file the problem is in; prefixed to the message when given.
    """

    def __init__(self, message: str, source: str | Path | None = None) -> None:
        self.source = None if source is None else str(source)
        self.message = message
        super().__init__(f"{self.source}: {message}" if self.source else message)
