"""Running one upload check in a short-lived child process with its own memory limit.

Parsing and validating an upload (decompressing an npz, reading HDF5 datasets, parsing CSV
or JSON) can take many times the upload's size in memory and seconds of CPU. Done in the API
process, that memory stays with the API after the request (the allocator keeps it) and the
parsing holds the GIL, so ``/healthz`` stalls. Here each check runs in a child forked from a
small ``forkserver`` process (which has the readers imported already):

* the child's address space is capped (``RLIMIT_AS``: what it had at its start plus
  ``memory_bytes``), so a file that needs more raises ``MemoryError`` there, which becomes a
  413 naming ``MOJU_UPLOAD_CHECK_MEMORY_BYTES``;
* the child exits after one check, so all of its memory goes back to the system;
* a child running longer than ``timeout`` seconds is killed (413 naming
  ``MOJU_UPLOAD_CHECK_TIMEOUT``); a child that dies (a signal) is a 422.

How many checks run at once is bounded by the caller (:mod:`service.uploads`), so parallel
uploads queue instead of multiplying memory.
"""

from __future__ import annotations

import logging
import multiprocessing
import multiprocessing.connection
import os
import resource
import signal
from collections.abc import Callable
from typing import Any, TypeVar

from moju_core.errors import MeasurementError, MeasurementTooLarge
from moju_core.feasibility import describe_bytes
from service.errors import InvalidInput, ServiceError, UploadTooLarge

logger = logging.getLogger(__name__)

T = TypeVar("T")

#: Modules the fork server imports once, so that each child starts in milliseconds (the
#: main module too: multiprocessing would otherwise import it again in every child).
PRELOAD = ["__main__", "service.input_check"]
#: Seconds a child that sent its answer gets to exit before it is killed.
_EXIT_GRACE = 5.0
#: Longest message carried back from a child (messages never echo an input whole).
_MAX_MESSAGE = 2000

_context: Any = None


def _fork_server() -> Any:
    """The ``forkserver`` multiprocessing context, preloading :data:`PRELOAD` (lazily)."""
    global _context
    if _context is None:
        context = multiprocessing.get_context("forkserver")
        context.set_forkserver_preload(PRELOAD)
        _context = context
    return _context


def _address_space() -> int:
    """Bytes of address space this process has mapped now (Linux /proc; 0 elsewhere)."""
    try:
        with open("/proc/self/statm") as handle:
            pages = int(handle.read().split()[0])
    except (OSError, ValueError, IndexError):
        return 0
    return pages * os.sysconf("SC_PAGE_SIZE")


def _limit_memory(memory_bytes: int) -> None:
    """Cap this process's address space at what it maps now plus ``memory_bytes``."""
    cap = _address_space() + memory_bytes
    resource.setrlimit(resource.RLIMIT_AS, (cap, cap))


def _out_of_memory(exc: BaseException) -> bool:
    """True when ``exc`` is, or was raised because of, a ``MemoryError``."""
    seen: BaseException | None = exc
    while seen is not None:
        if isinstance(seen, MemoryError):
            return True
        seen = seen.__cause__ or seen.__context__
    return False


def _outcome(function: Callable[[Any], Any], argument: Any, memory_bytes: int) -> tuple:
    """Run ``function(argument)``; its value or the kind and message of its failure."""
    try:
        _limit_memory(memory_bytes)
        return ("ok", function(argument))
    except MemoryError:
        return ("memory", "")
    except Exception as exc:
        if _out_of_memory(exc):  # a reader that wrapped it in its own error
            return ("memory", "")
        return _refusal(exc)


def _refusal(exc: Exception) -> tuple[str, str]:
    """The kind (413 or 422) and message of a check that refused its input."""
    if isinstance(exc, (MeasurementTooLarge, UploadTooLarge)):
        return ("too_large", str(exc))
    if isinstance(exc, (MeasurementError, ServiceError)):
        return ("invalid", str(exc))
    # A reader that failed in a way it does not describe: logged with its traceback.
    logger.error("checking an upload failed unexpectedly", exc_info=exc)
    return ("invalid", f"the file could not be read ({type(exc).__name__}: {exc})")


def _child(
    connection: multiprocessing.connection.Connection,
    function: Callable[[Any], Any],
    argument: Any,
    memory_bytes: int,
) -> None:
    """Entry point of the child: one check, its outcome sent back, then exit."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C stops the API, which kills us
    outcome = _outcome(function, argument, memory_bytes)
    try:
        connection.send(outcome)
    except MemoryError:
        connection.send(("memory", ""))
    connection.close()


def _shorten(message: str) -> str:
    if len(message) <= _MAX_MESSAGE:
        return message
    return message[:_MAX_MESSAGE] + " ... (message shortened)"


def run_here(function: Callable[[Any], T], argument: Any) -> T:
    """``function(argument)`` in this process, its refusals raised as by :func:`run_check`
    (blocking: run in a worker thread). Only for inputs known to be small."""
    try:
        return function(argument)
    except MemoryError:
        raise UploadTooLarge("this server has no memory left to check the upload") from None
    except Exception as exc:
        kind, message = _refusal(exc)
    if kind == "too_large":
        raise UploadTooLarge(_shorten(message))
    raise InvalidInput(_shorten(message))


def run_check(
    function: Callable[[Any], T], argument: Any, *, memory_bytes: int, timeout: float
) -> T:
    """``function(argument)`` in a fresh child process (blocking: run in a worker thread).

    Parameters
    ----------
    function : callable
        A module-level function of a module in :data:`PRELOAD` (it is pickled by name).
    argument : picklable
        Its only argument.
    memory_bytes : int
        Bytes the child may allocate beyond what it maps at its start.
    timeout : float
        Seconds the child may run.

    Raises
    ------
    UploadTooLarge
        The check needed more than ``memory_bytes``, ran longer than ``timeout``, or the
        function refused a size (413).
    InvalidInput
        The function refused the input, or the child died (422).
    """
    context = _fork_server()
    receiver, sender = context.Pipe(duplex=False)
    process = context.Process(
        target=_child, args=(sender, function, argument, memory_bytes), daemon=True
    )
    process.start()
    sender.close()
    answered = False
    try:
        if not receiver.poll(timeout):
            raise UploadTooLarge(
                f"checking the upload took longer than {timeout:g} s, the most this server "
                "allows (MOJU_UPLOAD_CHECK_TIMEOUT); send fewer frames or points"
            )
        answered = True
        try:
            kind, value = receiver.recv()
        except EOFError:
            process.join(_EXIT_GRACE)
            raise InvalidInput(
                "the file could not be read: the process checking it ended abruptly "
                f"(exit code {process.exitcode}); check that it is a valid npz, HDF5 or CSV "
                "file"
            ) from None
    finally:
        receiver.close()
        if answered:
            process.join(_EXIT_GRACE)
        if process.is_alive():
            process.kill()
            process.join()
        process.close()
    if kind == "ok":
        return value
    if kind == "memory":
        raise UploadTooLarge(
            f"reading and checking this upload needs more than {describe_bytes(memory_bytes)} "
            "of memory, the most this server gives one upload (MOJU_UPLOAD_CHECK_MEMORY_BYTES); "
            "send fewer frames or points, or leave out the optional arrays (gt, visibility)"
        )
    if kind == "too_large":
        raise UploadTooLarge(_shorten(value))
    raise InvalidInput(_shorten(value))
