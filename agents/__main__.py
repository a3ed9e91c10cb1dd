"""The ``bogie`` console script (also ``python -m bogie_agents``): :func:`bogie_agents.cli.main`
in a process tuned for a short life.

- Before numpy, numba and the package load, Python's young-generation GC threshold goes from
  700 to ``GC_YOUNG_THRESHOLD``: their start-up creates a few hundred thousand objects, and at
  700 the collector spent 0.15-0.2 s of the ~1-s ``bogie curving`` scanning them
  (docs/performance.md). Collection still runs, every 50,000 net allocations.
- On the way out, :func:`gc.freeze`: the interpreter's final collections then skip those
  objects (0.2-0.3 s of ``bogie curving``). Finalizers of objects caught in reference cycles do
  not run at exit; every command has written its results (atomically) before it returns, and
  nothing in the package relies on such finalizers.

Importing :mod:`bogie_agents.cli` as a library (tests, other programs) changes neither.
"""

from __future__ import annotations

import gc
import sys

GC_YOUNG_THRESHOLD = 50_000


def main() -> int:
    """Run the ``bogie`` command line on ``sys.argv``."""
    gc.set_threshold(GC_YOUNG_THRESHOLD, *gc.get_threshold()[1:])
    from .cli import main as cli_main

    try:
        return cli_main()
    finally:
        gc.freeze()


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
