"""Tests of moju_core.file_types: the files the project writes are recognised by their heads."""

from __future__ import annotations

import io

import h5py
import numpy as np
import pytest

from moju_core.file_types import HEAD_BYTES, array_file_type, video_extension


def _head(write) -> bytes:
    buffer = io.BytesIO()
    write(buffer)
    return buffer.getvalue()[:HEAD_BYTES]


def _h5(buffer: io.BytesIO) -> None:
    with h5py.File(buffer, "w") as h5:
        h5["W"] = np.zeros((4, 3))


@pytest.mark.parametrize(
    ("write", "expected"),
    [
        (lambda b: np.savez(b, W=np.zeros((4, 3))), "npz"),
        (lambda b: np.save(b, np.zeros((4, 3))), "npy"),
        (_h5, "h5"),
        (lambda b: b.write(b"frame,point,x,y\n0,0,1,2\n"), None),
    ],
)
def test_array_files_are_told_by_their_first_bytes(write, expected):
    assert array_file_type(_head(write)) == expected


@pytest.mark.parametrize(
    ("head", "expected"),
    [
        (b"\x00\x00\x00\x20ftypisom", ".mp4"),
        (b"\x1a\x45\xdf\xa3\x9f\x42\x86\x81\x01\x42\xf7\x81", ".webm"),
        (b"RIFF\x00\x00\x00\x00AVI ", ".avi"),
        (b"RIFF\x00\x00\x00\x00WAVE", None),
        (b"PK\x03\x04" + bytes(8), None),
    ],
)
def test_videos_are_told_by_their_first_bytes(head, expected):
    assert video_extension(head) == expected
