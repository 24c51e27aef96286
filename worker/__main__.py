"""``python -m worker [--burst]``: run one worker configured by the MOJU_* environment.

``moju worker`` is the documented command; this form is what ``moju serve`` starts, so that
it works even when the ``moju`` script is not on PATH.
"""

from __future__ import annotations

import sys

from worker.runner import run_worker

if __name__ == "__main__":
    run_worker(burst="--burst" in sys.argv[1:])
