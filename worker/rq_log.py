"""RQ's log line for a job that returned, corrected for jobs that did not finish.

RQ logs "Job OK" (and "Successfully completed job ...") whenever the job function returns.
:func:`worker.jobs.run_reconstruction` returns for a cancelled, failed, superseded or
deleted job too (the job's outcome is in its record, not in an exception), so RQ's line
would call a cancelled job OK. The job function notes each outcome here
(:func:`note_outcome`), in the work horse that then logs RQ's lines, and
:class:`OutcomeFilter` on RQ's worker logger rewrites those two lines of a job that did not
finish to name its outcome. Lines of other jobs pass unchanged.
"""

from __future__ import annotations

import logging

__all__ = ["OutcomeFilter", "install", "note_outcome"]

#: RQ's logger of its worker and work horse.
RQ_WORKER_LOGGER = "rq.worker"

# The last job this process ran, (RQ job id, status), until RQ has logged it. A work horse runs
# one job; RQ logs its lines right after the job function returned.
_last: tuple[str, str] | None = None


def note_outcome(rq_id: str, status: str) -> None:
    """Remember that RQ job ``rq_id`` ended as ``status`` (a job status value)."""
    global _last
    _last = (rq_id, status)


class OutcomeFilter(logging.Filter):
    """Rewrites RQ's success lines of a job whose noted outcome is not ``finished``."""

    def filter(self, record: logging.LogRecord) -> bool:
        if _last is None or _last[1] == "finished":
            return True
        rq_id, status = _last
        args = record.args if isinstance(record.args, tuple) else ()
        if str(record.msg).startswith("Successfully completed") and len(args) == 3:
            # 'Successfully completed [%s job|job %s] in %ss on worker %s', logged first
            record.msg = f"Job {rq_id} returned, {status}, in %ss on worker %s"
            record.args = tuple(args[1:])
        elif len(args) == 4 and "Job OK" in str(args[2]) and str(args[3]) == rq_id:
            # 'Worker %s: %s: %s (%s)' with (worker, queue, 'Job OK', job id), logged last
            record.args = (args[0], args[1], f"Job ended, {status}", args[3])
            note_outcome(rq_id, "finished")  # logged: nothing more to correct
        return True


def install() -> None:
    """Put :class:`OutcomeFilter` on RQ's worker logger (once per process)."""
    logger = logging.getLogger(RQ_WORKER_LOGGER)
    if not any(isinstance(existing, OutcomeFilter) for existing in logger.filters):
        logger.addFilter(OutcomeFilter())
