"""Deleting the files of jobs whose records expired (``MOJU_RESULT_TTL``).

Redis expires a job's record on its own; the files on the shared volume need this sweep. It is
idempotent and safe to run from several API processes at once.
"""

from __future__ import annotations

import logging
import time

from service.job_store import JobStore
from service.storage import Storage

logger = logging.getLogger(__name__)

#: A job directory younger than this is never swept: the API writes a job's input before it
#: creates the record, and a sweep must not delete files of a job being submitted.
GRACE_SECONDS = 600.0


def sweep(store: JobStore, storage: Storage, *, grace_seconds: float = GRACE_SECONDS) -> int:
    """Delete files of jobs that have no record any more; return how many jobs were swept."""
    store.prune_index()
    now = time.time()
    candidates = [
        job_id for job_id, modified in storage.stored_jobs() if now - modified > grace_seconds
    ]
    if not candidates:
        return 0
    swept = 0
    for job_id, has_record in zip(candidates, store.exists(candidates), strict=True):
        if not has_record:
            storage.delete(job_id)
            swept += 1
    if swept:
        logger.info("deleted the files of %d expired job(s)", swept)
    return swept
