"""Shared helpers of the bad-input battery (``tests/test_bad_input_*.py``).

Every case goes through the real CLI (typer's ``CliRunner``, in process) and
asserts the same contract: the exit code, a message naming the file and the
key or column, no traceback, and that what was already in the run directory
is byte-identical afterwards.
"""

from __future__ import annotations

import hashlib
from pathlib import Path

from typer.testing import CliRunner

from bpsflow.cli import app

runner = CliRunner()


def invoke(*args: object):
    """Run ``bpsflow ARGS`` in process; the result has ``exit_code``, ``output``, ``exception``."""
    return runner.invoke(app, [str(arg) for arg in args])


def all_text(result) -> str:
    """Standard output and standard error of a CLI result, as one string."""
    text = result.output
    try:
        text += result.stderr
    except (ValueError, AttributeError):
        pass
    return text


def assert_clean_error(result, *needles: str, code: int = 2) -> str:
    """The command failed with ``code``, no traceback, and its message holds every needle.

    An exception other than ``SystemExit`` escaping the command counts as a
    traceback: the installed ``bpsflow`` would print one.
    """
    text = all_text(result)
    assert "Traceback" not in text, text
    assert result.exception is None or isinstance(result.exception, SystemExit), (
        f"uncaught {type(result.exception).__name__}: {result.exception}\n{text}")
    assert result.exit_code == code, f"exit {result.exit_code}, expected {code}:\n{text}"
    flat = " ".join(text.split())
    for needle in needles:
        assert needle in flat, f"{needle!r} not in the message:\n{text}"
    return text


def assert_ok(result) -> str:
    text = all_text(result)
    assert result.exit_code == 0, f"exit {result.exit_code}:\n{text}"
    assert "Traceback" not in text, text
    return text


def snapshot(folder: Path) -> dict[str, str]:
    """SHA-256 of every file under ``folder``, keyed by its relative path."""
    folder = Path(folder)
    if not folder.exists():
        return {}
    return {str(path.relative_to(folder)): hashlib.sha256(path.read_bytes()).hexdigest()
            for path in sorted(folder.rglob("*")) if path.is_file()}


def assert_unchanged(before: dict[str, str], folder: Path, ignore: tuple[str, ...] = ()) -> None:
    """Every file of ``before`` is still there, byte-identical (new files are allowed)."""
    after = snapshot(folder)
    for name, digest in before.items():
        if any(name.startswith(prefix) for prefix in ignore):
            continue
        assert name in after, f"{name} was deleted"
        assert after[name] == digest, f"{name} was changed"
