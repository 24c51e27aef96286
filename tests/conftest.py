"""Fixtures shared by every test package: a throwaway Redis (see tests/redis_server.py).

The core's tests (``tests/moju_core``) run with the core install and the ``core-test`` extra
alone: nothing here imports the service, and the video tests are skipped without OpenCV.

Property-based tests (hypothesis, schemathesis) draw the same examples on every run by default,
so that CI passes or fails on the code alone, not on what a random draw happened to try.
``HYPOTHESIS_PROFILE=explore python -m pytest tests/moju_core/test_io_fuzz.py`` draws fresh
random examples to look for new failures (2,500 per property were once drawn that way).
"""

import os

from hypothesis import settings
from redis_server import redis_server, redis_url  # noqa: F401 - fixtures, used by name

settings.register_profile("reproducible", derandomize=True)
settings.register_profile("explore", derandomize=False)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "reproducible"))
