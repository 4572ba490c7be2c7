"""Whether a file is IDF text: ``Type, field, ...;`` objects of EnergyPlus object types.

The model's IDF and every ``model.idf_objects`` snippet are checked when the
config loads (:func:`check_idf_file`), so no command reads, echoes or runs a
file that is not an IDF (a binary file, a system file named by mistake, an
object that never ends). The message names the config key, the file and the
line, never the file's content; only a near miss of a real type name is
repeated, with the type it resembles.
"""

from __future__ import annotations

import difflib
import re
from dataclasses import dataclass
from pathlib import Path

from bpsflow.errors import BpsflowError
from bpsflow.simulation.field_limits import UnknownFieldError, known_object_types, object_fields

__all__ = ["IdfStatement", "idf_statements", "check_idf_file"]

#: What an IDF object looks like, for messages.
_EXPECTED = "an IDF object: Type, field, ...; (Type an EnergyPlus 25.2 object type)"
_TYPE_LIKE = re.compile(r"^[A-Za-z][A-Za-z0-9:_\- ]{0,99}$")


@dataclass(frozen=True)
class IdfStatement:
    """One ``...;`` statement of an IDF: the line it starts on and the text before its first comma."""

    line: int
    head: str


def idf_statements(text: str) -> tuple[list[IdfStatement], int | None]:
    """The statements of IDF text (comments removed) and the line of an unterminated one.

    Returns
    -------
    statements : list of IdfStatement
    unterminated : int or None
        The line where text starts that no ``;`` ends.
    """
    statements: list[IdfStatement] = []
    start: int | None = None
    buffer: list[str] = []
    for number, line in enumerate(text.splitlines(), 1):
        code = line.split("!", 1)[0]
        while True:
            head, separator, code = code.partition(";")
            if start is None and head.strip():
                start = number
            if start is not None:
                buffer.append(head)
            if not separator:
                break
            if start is not None:
                statements.append(IdfStatement(start, "\n".join(buffer).split(",", 1)[0].strip()))
            start, buffer = None, []
            if not code.strip():
                break
    return statements, start


def _decoded(path: Path, key: str) -> str:
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise BpsflowError(f"{key}: cannot read the IDF file: {exc.strerror or exc}",
                           source=path) from None
    if b"\x00" in data:
        raise BpsflowError(f"{key}: not an IDF file (binary content); expected {_EXPECTED}",
                           source=path)
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError:
        return data.decode("latin-1")


def check_idf_file(path: Path, key: str) -> int:
    """Check that a file holds only IDF objects of EnergyPlus types; return how many.

    Parameters
    ----------
    path : Path
        The IDF or snippet.
    key : str
        The config key that lists it (``model.idf_objects[0]``), for messages.

    Raises
    ------
    BpsflowError
        Naming the key, the file and the line of the first statement that is
        not an IDF object of a known type (or that never ends), without
        repeating the file's text.
    """
    path = Path(path)
    text = _decoded(path, key)
    statements, unterminated = idf_statements(text)
    for statement in statements:
        try:
            if not _TYPE_LIKE.match(statement.head):
                raise UnknownFieldError("not a type name")
            object_fields(statement.head)
        except UnknownFieldError:
            raise BpsflowError(f"{key}: line {statement.line}: expected {_EXPECTED}; this is not "
                               f"one{_did_you_mean(statement.head)}", source=path) from None
    if unterminated is not None:
        raise BpsflowError(f"{key}: line {unterminated}: expected {_EXPECTED}; the text from "
                           f"here on never ends with ';'", source=path)
    if not statements:
        raise BpsflowError(f"{key}: no IDF objects in the file; expected {_EXPECTED}",
                           source=path)
    return len(statements)


def _did_you_mean(head: str) -> str:
    """`` ('Materal' is not an object type; did you mean Material?)`` for a near miss, else ``''``.

    Only a near miss of a real type is repeated: any other text of the file is
    not shown (it may be anything, e.g. a system file named by mistake).
    """
    if not _TYPE_LIKE.match(head):
        return ""
    close = difflib.get_close_matches(head.upper(), list(known_object_types()), n=1, cutoff=0.85)
    if not close:
        return ""
    return f" ('{head}' is not an object type; did you mean {known_object_types()[close[0]]}?)"
