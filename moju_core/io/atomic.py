"""Writing a file so that it appears complete under its final name, or not at all."""

from __future__ import annotations

import contextlib
import os
import uuid
from collections.abc import Iterator
from pathlib import Path

from moju_core.io._sources import PathLike


@contextlib.contextmanager
def atomic_output(path: PathLike) -> Iterator[Path]:
    """Give a temporary path next to ``path`` that is renamed to ``path`` on success.

    The temporary file is created empty in the same directory (so the rename is atomic on
    POSIX), flushed to disk before the rename, and removed if the ``with`` body raises: no
    half-written file ever appears under the final name, and none is left behind.

    Parameters
    ----------
    path : str or os.PathLike
        Final location of the file.

    Yields
    ------
    Path
        The temporary file to write (it exists, empty; writers may truncate or replace it).
    """
    path = Path(path)
    temporary = path.with_name(f".{path.name}.{uuid.uuid4().hex[:12]}.tmp")
    # O_EXCL never clobbers a file; mode 0o666 lets the umask decide the permissions as for any
    # open(), where NamedTemporaryFile would leave the result readable by its owner only.
    os.close(os.open(temporary, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666))
    try:
        yield temporary
        descriptor = os.open(temporary, os.O_RDONLY)
        try:
            os.fsync(descriptor)
        finally:
            os.close(descriptor)
        os.replace(temporary, path)
    except BaseException:
        temporary.unlink(missing_ok=True)
        raise
