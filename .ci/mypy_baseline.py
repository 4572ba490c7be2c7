"""Compare mypy's errors per module with the baseline: the count may only shrink.

Usage: ``mypy bpsflow | python .ci/mypy_baseline.py .ci/mypy-baseline.txt [--update]``.
The baseline lists ``<errors> <module path>`` per line. A module with more errors
than its baseline (or errors and no baseline line) fails; ``--update`` rewrites
the baseline from this run, for after errors were fixed.
"""

from __future__ import annotations

import re
import sys
from collections import Counter
from pathlib import Path

ERROR = re.compile(r"^(?P<path>[^:\s]+\.py):\d+: error:")


def main(argv: list[str]) -> int:
    baseline_path = Path(argv[1])
    found = Counter(m["path"] for line in sys.stdin if (m := ERROR.match(line)))
    if "--update" in argv:
        baseline_path.write_text("".join(f"{n} {p}\n" for p, n in sorted(found.items())))
        print(f"mypy baseline: {sum(found.values())} errors in {len(found)} modules written")
        return 0
    baseline = Counter()
    for line in baseline_path.read_text().splitlines():
        if line.strip():
            count, path = line.split(maxsplit=1)
            baseline[path] = int(count)
    worse = {p: (n, baseline[p]) for p, n in found.items() if n > baseline[p]}
    for path, (now, before) in sorted(worse.items()):
        print(f"mypy: {path}: {now} errors, baseline {before} (fix the new ones)")
    total, limit = sum(found.values()), sum(baseline.values())
    print(f"mypy: {total} errors (baseline {limit})"
          + ("; run with --update to lower the baseline" if total < limit and not worse else ""))
    return 1 if worse else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
