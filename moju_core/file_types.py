"""What kind of file a byte string starts with: the one table of file signatures.

Measurement and result files are told apart by their first bytes before their names (a
browser or ``curl`` may send any name); videos, masks and image frames likewise. The file
readers (:mod:`moju_core.io`, :mod:`moju_core.footage.video`), the result viewer and the upload
validation of the service all read their signatures from here.
"""

from __future__ import annotations

from typing import Literal

__all__ = [
    "HDF5_MAGIC",
    "HEAD_BYTES",
    "JPEG_MAGIC",
    "NPY_MAGIC",
    "PNG_MAGIC",
    "ZIP_MAGIC",
    "array_file_type",
    "video_extension",
]

#: A zip archive's local file header; an npz is a zip of .npy members.
ZIP_MAGIC = b"PK\x03\x04"
#: The HDF5 superblock signature (at offset 0 for the files h5py writes).
HDF5_MAGIC = b"\x89HDF\r\n\x1a\n"
#: A bare .npy array (not accepted as measurements: its array has no name).
NPY_MAGIC = b"\x93NUMPY"
#: PNG signature (masks, image frames).
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
#: JPEG start-of-image marker (image frames).
JPEG_MAGIC = b"\xff\xd8"
#: Bytes of a file's head that every test here needs (the AVI test reads bytes 8 to 12).
HEAD_BYTES = 12


def array_file_type(head: bytes) -> Literal["npz", "h5", "npy"] | None:
    """``"npz"``, ``"h5"`` or ``"npy"`` for a file starting with ``head``; None for anything
    else (CSV, or a file to be told by its name)."""
    if head.startswith(ZIP_MAGIC):
        return "npz"
    if head.startswith(HDF5_MAGIC):
        return "h5"
    if head.startswith(NPY_MAGIC):
        return "npy"
    return None


def video_extension(head: bytes) -> Literal[".mp4", ".webm", ".avi"] | None:
    """The extension of a video file starting with ``head`` (its first :data:`HEAD_BYTES`
    bytes or more): ``.mp4`` (ISO media, ``ftyp`` box), ``.webm`` (EBML) or ``.avi`` (RIFF
    AVI); None for anything else."""
    if head[4:8] == b"ftyp":
        return ".mp4"
    if head[:4] == b"\x1a\x45\xdf\xa3":
        return ".webm"
    if head[:4] == b"RIFF" and head[8:12] == b"AVI ":
        return ".avi"
    return None
