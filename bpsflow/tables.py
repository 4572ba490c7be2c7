"""Reading users' CSV tables with errors that name the file, the column and the row."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import pandas as pd

from bpsflow.errors import BpsflowError


def read_table(path: Path, required: Sequence[str], what: str, where: str = "",
               text_columns: Sequence[str] = ("timestamp",),
               numeric_columns: Sequence[str] | None = None) -> pd.DataFrame:
    """Read a CSV whose columns other than ``text_columns`` are numbers.

    Parameters
    ----------
    path : Path
    required : sequence of str
        Columns that must be present.
    what : str
        What the file is, for messages ("detailed measurements").
    where : str
        The config key that names the columns, if any, for messages.
    text_columns : sequence of str
        Columns left as read (timestamps).
    numeric_columns : sequence of str, optional
        Only these columns must be numbers (default: every column but
        ``text_columns``).

    Raises
    ------
    BpsflowError
        The file is missing or does not parse, a required column is missing, or
        a cell of a numeric column is not a number (naming its row).
    """
    path = Path(path)
    if not path.is_file():
        raise BpsflowError(f"{what} file not found: {path}")
    try:
        frame = pd.read_csv(path)
    except Exception as exc:  # pandas raises many parser errors
        raise BpsflowError(f"cannot parse the {what} file: {exc}", source=path) from None
    missing = [c for c in required if c not in frame.columns]
    if missing:
        listed = ", ".join(required) if len(required) <= 12 else \
            ", ".join(list(required)[:12]) + f", ... ({len(required)} in all)"
        raise BpsflowError(f"missing column(s) {missing} (expected the {what} columns: {listed})"
                           + (f" ({where})" if where else ""), source=path)
    checked = frame.columns if numeric_columns is None else list(numeric_columns)
    for column in checked:
        if column in text_columns:
            continue
        numbers = pd.to_numeric(frame[column], errors="coerce")
        bad = numbers.isna() & frame[column].notna()
        if bad.any():
            raise BpsflowError(f"column '{column}', row {int(bad.to_numpy().argmax()) + 2}: "
                               f"'{frame[column][bad].iloc[0]}' is not a number", source=path)
        frame[column] = numbers
    return frame
