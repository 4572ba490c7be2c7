"""Names that become parts of file names: the one rule, and its schema type.

Tests, outputs, parameters, periods and calibration scenarios are named in
the config, and their names end up in file names (``band_<test>_<output>.png``,
``morris_<test>_<output>.png``, ``heldout_<output>_<resolution>.png``,
``<parameter>_samples.csv``) and in table columns. A name is therefore
letters, digits, ``_``, ``-`` and ``.``, starting with a letter or ``_``:
no path separator, no ``.``/``..``, not empty, no leading ``-`` (read as an
option by shell tools), no control character. The writers still resolve
every such file inside its folder (:func:`bpsflow.files.inside`).
"""

from __future__ import annotations

import re
from typing import Annotated

from pydantic import AfterValidator

#: The rule (a whole-string match: no trailing newline slips through ``$``).
NAME_PATTERN = re.compile(r"[A-Za-z_][A-Za-z0-9_.\-]*")

#: Two names joined in one file name (``band_<test>_<output>.png``) stay under 255 bytes.
MAX_LENGTH = 100

RULE = ("expected letters, digits, '_', '-' or '.', starting with a letter or '_' "
        "(it names files)")


def check_name(name: str) -> str:
    """``name`` if it follows :data:`NAME_PATTERN`, else a ``ValueError`` stating the rule.

    Parameters
    ----------
    name : str

    Returns
    -------
    str
        ``name`` unchanged.

    Raises
    ------
    ValueError
        Naming the offending name (``repr``, so control characters show) and the rule.
    """
    if not NAME_PATTERN.fullmatch(name):
        raise ValueError(f"name {name!r}: {RULE}")
    if len(name) > MAX_LENGTH:
        raise ValueError(f"name {name[:20]!r}... has {len(name)} characters: at most {MAX_LENGTH} "
                         f"(file names join two names and must stay under the file system's 255)")
    return name


#: A config name that may become part of a file name.
SafeName = Annotated[str, AfterValidator(check_name)]
