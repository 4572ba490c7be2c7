"""Progress off a terminal: plain lines while the work goes on, not one bar at its end."""

from __future__ import annotations

import io

from rich.console import Console
from rich.progress import BarColumn, TextColumn

from bpsflow.progress import LoggedProgress


def _console() -> tuple[Console, io.StringIO]:
    buffer = io.StringIO()
    return Console(file=buffer, force_terminal=False, width=100), buffer


def test_a_log_file_gets_a_line_per_tenth_and_per_new_step():
    console, buffer = _console()
    with LoggedProgress(TextColumn("{task.description}"), BarColumn(), console=console,
                        name="diagnose") as progress:
        task = progress.add_task("runs", total=20, failed=0)
        lines_at_start = buffer.getvalue().count("\n")
        for done in range(1, 21):
            progress.update(task, completed=done, failed=done // 10)
            if done == 2:
                # the first line is written while the work goes on, not when it ends
                assert buffer.getvalue().count("\n") > lines_at_start
        progress.update(task, description="round 2")
    lines = buffer.getvalue().splitlines()
    assert lines[0] == "diagnose runs: 0/20, 0 s"
    tenths = [line for line in lines if line.startswith("diagnose runs: ")]
    assert len(tenths) == 11                 # the start and each tenth, no more
    assert "diagnose runs: 20/20 (2 failed)" in lines[-2]
    assert lines[-1].startswith("diagnose round 2: 20/20")
    assert "━" not in buffer.getvalue()      # no bar drawn into the file


def test_a_terminal_gets_the_bar_and_no_plain_lines():
    buffer = io.StringIO()
    console = Console(file=buffer, force_terminal=True, width=100)
    with LoggedProgress(TextColumn("{task.description}"), BarColumn(), console=console,
                        name="diagnose") as progress:
        task = progress.add_task("runs", total=4)
        progress.update(task, completed=4)
    assert "diagnose runs: " not in buffer.getvalue()


def test_disabled_progress_says_nothing():
    console, buffer = _console()
    with LoggedProgress(TextColumn("{task.description}"), console=console,
                        disable=True) as progress:
        task = progress.add_task("runs", total=4)
        progress.update(task, completed=4)
    assert buffer.getvalue() == ""


def test_a_step_that_does_not_advance_still_says_it_is_running():
    """A diagnosis's base fit (minutes of simulations) left the log at '0/5, 0 s'."""
    import time

    console, buffer = _console()
    with LoggedProgress(TextColumn("{task.description}"), console=console, every=0.2,
                        name="diagnose") as progress:
        task = progress.add_task("fits", total=5)
        time.sleep(0.9)
        progress.advance(task)
    lines = buffer.getvalue().splitlines()
    assert sum("still running" in line for line in lines) >= 2
    assert lines[-1].startswith("diagnose fits: 1/5") and "still running" not in lines[-1]
