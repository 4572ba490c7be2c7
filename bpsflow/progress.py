"""Progress of long work, on a terminal and in a log file alike.

rich draws a live bar only on a terminal; on a console that is not one (output
redirected to a file, a CI log, a batch job) it renders the bar once, when the
work ends, so a 30-minute diagnosis said nothing for 30 minutes. :class:`LoggedProgress`
is a rich ``Progress`` that, off a terminal, prints a plain line instead: when a
task starts, at each tenth of it, when its description changes, at least every
``every`` seconds while it advances, and when it ends. While a task does not
advance (a step of minutes, such as a fit of many simulations), a line every
``every`` seconds says it is still running, so a log never goes quiet for long.
"""

from __future__ import annotations

import threading
import time
from typing import Any

from rich.console import Console
from rich.progress import Progress, TaskID

#: Seconds between two plain lines of one task that advances slowly.
PLAIN_EVERY_S = 60.0


class LoggedProgress(Progress):
    """A rich ``Progress`` that writes plain lines when its console is not a terminal."""

    def __init__(self, *columns: Any, console: Console, disable: bool = False,
                 every: float = PLAIN_EVERY_S, name: str = "", **kwargs: Any) -> None:
        self._plain = not disable and not console.is_terminal
        self._name = f"{name} " if name else ""
        super().__init__(*columns, console=console, disable=disable or self._plain, **kwargs)
        self._plain_console = console
        self._every = every
        # per task, what its last line said: time, tenth, description, completed
        self._said: dict[TaskID, tuple[float, int, str, float]] = {}
        self._quiet = threading.Event()
        self._heartbeat: threading.Thread | None = None

    def start(self) -> None:
        super().start()
        if self._plain and self._heartbeat is None:
            self._quiet.clear()
            self._heartbeat = threading.Thread(target=self._beat, daemon=True,
                                               name="bpsflow-progress")
            self._heartbeat.start()

    def _beat(self) -> None:
        """Say 'still running' for every unfinished task whose last line is ``every`` s old."""
        while not self._quiet.wait(min(self._every / 4, 5.0)):
            now = time.monotonic()
            with self._lock:
                stale = [task_id for task_id, said in self._said.items()
                         if now - said[0] >= self._every and not self._tasks[task_id].finished]
            for task_id in stale:
                self._say(task_id, still=True)

    def add_task(self, description: str, start: bool = True, total: float | None = 100.0,
                 completed: int = 0, visible: bool = True, **fields: Any) -> TaskID:
        task_id = super().add_task(description, start=start, total=total, completed=completed,
                                   visible=visible, **fields)
        if self._plain:
            self._say(task_id, force=True)
        return task_id

    def update(self, task_id: TaskID, **kwargs: Any) -> None:  # type: ignore[override]
        super().update(task_id, **kwargs)
        if self._plain:
            self._say(task_id)

    def advance(self, task_id: TaskID, advance: float = 1) -> None:
        super().advance(task_id, advance)
        if self._plain:
            self._say(task_id)

    def stop(self) -> None:
        self._quiet.set()
        if self._heartbeat is not None:
            self._heartbeat.join(timeout=10)
            self._heartbeat = None
        if self._plain:
            for task_id in list(self._said):
                self._say(task_id, force=True, final=True)
        super().stop()

    def _say(self, task_id: TaskID, force: bool = False, final: bool = False,
             still: bool = False) -> None:
        with self._lock:   # the heartbeat thread says lines too
            self._say_locked(task_id, force, final, still)

    def _say_locked(self, task_id: TaskID, force: bool, final: bool, still: bool) -> None:
        task = self._tasks[task_id]
        total = task.total or 0
        tenth = int(10 * task.completed / total) if total else 0
        now = time.monotonic()
        last_time, last_tenth, last_description, last_completed = self._said.get(
            task_id, (now, -1, "", -1.0))
        description = str(task.description)
        if final:
            if task.completed == last_completed and description == last_description:
                return
        elif not (force or still or tenth > last_tenth or description != last_description
                  or (now - last_time >= self._every and task.completed != last_completed)):
            return
        self._said[task_id] = (now, tenth, description, task.completed)
        failed = task.fields.get("failed")
        self._plain_console.print(
            f"{self._name}{description}: {task.completed:g}" + (f"/{total:g}" if total else "")
            + (f" ({failed} failed)" if failed else "")
            + f", {task.elapsed or 0.0:.0f} s" + (" (still running)" if still else ""),
            highlight=False, markup=False)
