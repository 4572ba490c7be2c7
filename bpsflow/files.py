"""Reading the user's text files, and writing result files: JSON with one set of
conversions, and atomic writes.

Every file bpsflow writes for a user or for a later command goes through
here, so that

* a file is either the old one or the complete new one, never half written:
  the content goes to a temporary file in the same folder (same file system)
  which then replaces the target with :func:`os.replace` — an interrupted run
  or a parallel reader never sees a truncated ``calibration.json``. (No
  ``fsync``: this guards against interrupted processes, not power loss, and
  costs nothing per file);
* nothing lands outside the folder it belongs to: a file name built from a
  config name (a test, an output, a measured column) is resolved with
  :func:`inside`, which refuses a name that would leave its root folder
  (``../x``, an absolute path) whatever the schema let through;
* JSON means the same thing everywhere: numpy scalars and arrays, pandas
  timestamps and paths are converted the same way in every module, and
  non-finite floats (NaN, ±inf) are written as ``null``, because JSON has no
  literal for them (Python's ``NaN`` token is not JSON, and strict readers
  such as ``jq`` or a browser reject the file).
"""

from __future__ import annotations

import datetime as _dt
import json
import math
import os
import tempfile
from collections.abc import Callable, Mapping
from pathlib import Path, PurePath
from typing import IO, Any

import numpy as np
import pandas as pd

from bpsflow.errors import BpsflowError

__all__ = ["inside", "jsonable", "read_parquet", "read_user_text", "save_figure", "write_bytes_atomic",
           "write_csv", "write_json", "write_npz", "write_parquet", "write_text_atomic"]


def read_user_text(path: str | os.PathLike, what: str) -> str:
    """The text of a file the user named, or a :class:`BpsflowError` that says what is wrong.

    Parameters
    ----------
    path : str or path-like
        The file.
    what : str
        What the file should be, for the message (e.g. ``"a YAML config"``).

    Raises
    ------
    BpsflowError
        When the file is missing, is a folder, cannot be read, or is not UTF-8
        text (a binary or mis-encoded file); its content is never echoed.
    """

    path = Path(path)
    if not path.exists():
        raise BpsflowError(f"file not found; expected {what}", source=path)
    if not path.is_file():
        raise BpsflowError(f"is not a file; expected {what}", source=path)
    try:
        return path.read_text(encoding="utf-8")
    except UnicodeDecodeError as exc:
        raise BpsflowError(f"not a UTF-8 text file (byte {exc.start} cannot be decoded); "
                           f"expected {what}", source=path) from None
    except OSError as exc:
        raise BpsflowError(f"cannot be read ({exc.strerror}); expected {what}",
                           source=path) from None


def read_parquet(path: str | os.PathLike, **kwargs: Any) -> pd.DataFrame:
    """A parquet file bpsflow wrote, or an error naming it when it cannot be read.

    A truncated or overwritten result file (a disk that filled up, an editor, a
    copy cut short) is bad input like any other: the message names the file and
    what to do, and nothing else in the folder is touched.
    """

    try:
        return pd.read_parquet(path, **kwargs)
    except FileNotFoundError:
        raise
    except (OSError, ValueError) as exc:   # pyarrow's ArrowInvalid is a ValueError
        raise BpsflowError(f"{path}: not a readable parquet file ({type(exc).__name__}: "
                           f"{str(exc).splitlines()[0] if str(exc) else 'unreadable'}); it was "
                           "damaged after bpsflow wrote it: restore it, or delete it and run "
                           "the command that writes it again") from None


def jsonable(value: Any) -> Any:
    """``value`` as plain JSON types (dict, list, str, int, float, bool, None).

    Conversions: mappings to dicts (keys to ``str``), tuples, lists, sets and
    numpy arrays and pandas Series/Index to lists, numpy scalars to their
    Python value, timestamps (pandas, numpy, ``datetime``), dates, times,
    durations and paths to their ``str()`` text (``"2025-07-05 00:00:00"``),
    ``pd.NA``/``NaT`` and non-finite floats (NaN, +inf, -inf) to ``None``.

    Parameters
    ----------
    value : object
        A nested structure of the types above.

    Returns
    -------
    object
        The same structure made only of JSON types.

    Raises
    ------
    TypeError
        ``value`` holds an object of another type (a silent ``str()`` would
        hide a bug in the caller).
    """
    if value is None or isinstance(value, (str, bool)):
        return value
    if isinstance(value, (int, float)) and not isinstance(value, np.generic):
        return _finite(value)
    if isinstance(value, np.datetime64):
        # .item() of a nanosecond datetime64 is a bare int: go through pandas
        return jsonable(pd.Timestamp(value))
    if isinstance(value, np.timedelta64):
        return jsonable(pd.Timedelta(value))
    if isinstance(value, np.generic):
        # np.bool_, np.int64, np.float32, np.str_ ...: their Python value
        return jsonable(value.item())
    if isinstance(value, Mapping):
        return {str(key): jsonable(item) for key, item in value.items()}
    if isinstance(value, (list, tuple, set, frozenset, np.ndarray, pd.Index, pd.Series)):
        items = value.tolist() if isinstance(value, (np.ndarray, pd.Index, pd.Series)) else value
        return [jsonable(item) for item in items]
    if value is pd.NaT or value is pd.NA:
        return None
    if isinstance(value, (pd.Timestamp, pd.Timedelta, _dt.date, _dt.time, _dt.timedelta,
                          PurePath)):
        return str(value)
    raise TypeError(f"not JSON serialisable: {type(value).__name__}")


def _finite(number: int | float) -> int | float | None:
    if isinstance(number, float) and not math.isfinite(number):
        return None
    return number


def write_json(path: str | os.PathLike, data: Any, *, sort_keys: bool = False) -> Path:
    """Write ``data`` as indented JSON (2 spaces, UTF-8, final newline), atomically.

    Values are converted by :func:`jsonable`; in particular NaN and ±inf are
    written as ``null``.

    Parameters
    ----------
    path : str or PathLike
        The file to (re)place; its folder must exist.
    data : object
        Anything :func:`jsonable` converts.
    sort_keys : bool, default False
        Sort the keys of every object (stable diffs of files kept in git).

    Returns
    -------
    Path
        ``path``.
    """
    text = json.dumps(jsonable(data), indent=2, sort_keys=sort_keys, allow_nan=False)
    return write_text_atomic(path, text + "\n")


def write_text_atomic(path: str | os.PathLike, text: str, encoding: str = "utf-8") -> Path:
    """Write ``text`` to ``path`` atomically (temporary file beside it, then ``os.replace``).

    Parameters
    ----------
    path : str or PathLike
        The file to (re)place; its folder must exist.
    text : str
        The whole content.
    encoding : str, default "utf-8"

    Returns
    -------
    Path
        ``path``.
    """
    return _atomic(path, lambda handle: handle.write(text.encode(encoding)))


def write_bytes_atomic(path: str | os.PathLike, content: bytes) -> Path:
    """Write ``content`` to ``path`` atomically (temporary file beside it, then ``os.replace``)."""
    return _atomic(path, lambda handle: handle.write(content))


def write_parquet(frame: pd.DataFrame, path: str | os.PathLike, **kwargs: Any) -> Path:
    """Write ``frame`` to a Parquet file atomically.

    Parameters
    ----------
    frame : DataFrame
    path : str or PathLike
        The file to (re)place; its folder must exist.
    **kwargs
        Passed to :meth:`pandas.DataFrame.to_parquet` (``index=False`` ...).

    Returns
    -------
    Path
        ``path``.
    """
    return _atomic(path, lambda handle: frame.to_parquet(handle, **kwargs))


def write_csv(frame: pd.DataFrame, path: str | os.PathLike, **kwargs: Any) -> Path:
    """Write ``frame`` to a CSV file atomically.

    Parameters
    ----------
    frame : DataFrame
    path : str or PathLike
        The file to (re)place; its folder must exist.
    **kwargs
        Passed to :meth:`pandas.DataFrame.to_csv` (``index=False``,
        ``float_format`` ...).

    Returns
    -------
    Path
        ``path``.
    """
    return _atomic(path, lambda handle: frame.to_csv(handle, **kwargs))


def write_npz(path: str | os.PathLike, **arrays: Any) -> Path:
    """Write ``arrays`` to a compressed ``.npz`` file atomically.

    Parameters
    ----------
    path : str or PathLike
        The file to (re)place; its folder must exist.
    **arrays
        Passed to :func:`numpy.savez_compressed`.

    Returns
    -------
    Path
        ``path``.
    """
    return _atomic(path, lambda handle: np.savez_compressed(handle, **arrays))


def save_figure(figure: Any, path: str | os.PathLike, **kwargs: Any) -> Path:
    """Save a matplotlib figure atomically, in the format its suffix names.

    Parameters
    ----------
    figure : matplotlib.figure.Figure
    path : str or PathLike
        The image to (re)place (``.png``, ``.pdf``, ``.svg`` ...); its folder must exist.
    **kwargs
        Passed to :meth:`matplotlib.figure.Figure.savefig` (``dpi`` ...).

    Returns
    -------
    Path
        ``path``.
    """
    path = Path(path)
    image_format = path.suffix.lstrip(".") or "png"
    return _atomic(path, lambda handle: figure.savefig(handle, format=image_format, **kwargs))


def user_cache_dir() -> Path:
    """bpsflow's folder for what it keeps between runs only to save time.

    ``$XDG_CACHE_HOME/bpsflow`` (``~/.cache/bpsflow``), or the system's
    temporary folder when the home cache cannot be written. Nothing in it is
    a result: deleting it costs time, never an answer.
    """
    root = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache")
    if not os.access(root if root.exists() else root.parent, os.W_OK):
        root = Path(tempfile.gettempdir())
    return root / "bpsflow"


def inside(root: str | os.PathLike, *parts: str | os.PathLike) -> Path:
    """``root / parts...``, resolved, refused when it would leave ``root``.

    File names built from user-given names (tests, outputs, scenarios,
    measured columns) go through here, so that no name (``../x``, ``/abs``, a
    symbolic link out) makes bpsflow write outside its run or output folder.

    Parameters
    ----------
    root : str or PathLike
        The folder every file must stay in.
    *parts : str or PathLike
        Path components below ``root`` (e.g. ``"figures", f"band_{name}.png"``).

    Returns
    -------
    Path
        The resolved path.

    Raises
    ------
    BpsflowError
        The path would lie outside ``root``, or a part holds a NUL or a line break.
    """

    base = Path(root).resolve()
    text = [str(part) for part in parts]
    if any(character in part for part in text for character in "\0\n\r"):
        raise BpsflowError(f"refusing to write {text!r} under {base}: a file name may not hold "
                           f"a NUL or line-break character")
    target = base.joinpath(*text).resolve()
    if target != base and base not in target.parents:
        raise BpsflowError(f"refusing to write {target}: it lies outside {base} (a name in the "
                           f"config or data holds a path separator or '..'; names may hold "
                           f"letters, digits, '_', '-' and '.')")
    return target


def refuse_foreign_file(path: str | os.PathLike, header: str, where: str, what: str) -> None:
    """Refuse to replace an existing file unless bpsflow wrote it (its first line ``header``).

    ``where`` names the option the path came from and ``what`` the kind of
    file bpsflow writes there, in the message.
    """
    path = Path(path)
    if not path.is_file():
        return
    with open(path, encoding="utf-8", errors="replace") as handle:
        first = handle.readline()
    if not first.startswith(header):
        raise BpsflowError(f"{where}: {path} exists and is not {what} bpsflow wrote; expected a "
                           f"new file (or an earlier {what.split(' ', 1)[-1]}, which is "
                           f"replaced)")


def check_writable_file(path: str | os.PathLike, where: str) -> Path:
    """Refuse, before any work, a file path that cannot be written; create its folder.

    ``where`` names the option or key the path came from, in the message.
    """
    path = Path(path)
    if path.is_dir():
        raise BpsflowError(f"{where}: {path} is a folder; expected a file path")
    folder = path.parent
    blocker = next((p for p in (folder, *folder.parents) if p.exists()), folder)
    if not blocker.is_dir():
        raise BpsflowError(f"{where}: cannot write {path}: {blocker} is a file; expected a folder")
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise BpsflowError(f"{where}: cannot create {folder} ({exc.strerror}); expected a "
                           f"folder bpsflow may write in") from None
    if not os.access(folder, os.W_OK | os.X_OK) or (path.exists()
                                                   and not os.access(path, os.W_OK)):
        raise BpsflowError(f"{where}: cannot write {path}: no permission; expected a file "
                           f"bpsflow may write")
    return path


def _atomic(path: str | os.PathLike, write: Callable[[IO[bytes]], Any]) -> Path:
    """Call ``write`` on a binary temporary file beside ``path``, then move it into place."""
    path = Path(path)
    if path.is_dir():
        raise BpsflowError(f"cannot write {path}: it is a folder; expected a file path")
    try:
        descriptor, name = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp",
                                            dir=path.parent)
    except OSError as exc:
        raise BpsflowError(f"cannot write {path}: {exc.strerror or type(exc).__name__} in "
                           f"{path.parent}; expected a folder bpsflow may write in") from None
    temporary = Path(name)
    try:
        with os.fdopen(descriptor, "wb") as handle:
            write(handle)
        # mkstemp makes the file 0600; a result file gets the usual permissions
        os.chmod(temporary, 0o666 & ~_UMASK)
        # atomic within one file system, hence the temporary file in the same folder
        os.replace(temporary, path)
    except OSError as exc:  # a full disk, a quota: the file named, the old one intact
        temporary.unlink(missing_ok=True)
        raise BpsflowError(f"cannot write {path}: {exc.strerror or type(exc).__name__}; the "
                           f"earlier file, if any, is unchanged") from None
    except BaseException:
        temporary.unlink(missing_ok=True)
        raise
    return path


def _current_umask() -> int:
    # The umask can only be read by setting it; done once, at import, rather than
    # per write, where another thread could create a file under the wrong mask.
    umask = os.umask(0o022)
    os.umask(umask)
    return umask


_UMASK = _current_umask()
