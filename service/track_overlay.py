"""The first frame of a video job with its tracks drawn on it, for the web page.

Every track gets a dot where it was last seen (red): where the dots lie short of the object's
motion, the tracker lost the point. Paths over the frames (green) are drawn for one track per
cell of :data:`PATH_SPACING` pixels (by where the track was first seen): the tracks of a dense
grid (every 4 pixels by default) drawn all at once are a solid green blob.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

_PATH_BGR = (80, 220, 80)
_END_BGR = (40, 40, 240)
#: Pixels between the starts of two drawn paths (at least).
PATH_SPACING = 16


def _spread_out(starts: np.ndarray, spacing: int) -> np.ndarray:
    """Indices of the first track in each ``spacing`` x ``spacing`` cell, from (P, 2) starts."""
    cells = np.floor(starts / spacing).astype(np.int64)
    _, first = np.unique(cells, axis=0, return_index=True)
    return np.sort(first)


def overlay_png(first_frame: Path, tracks_file: Path) -> bytes:
    """PNG bytes of ``first_frame`` with the tracks of ``tracks_file`` drawn on it.

    ``tracks_file`` is a job's ``tracks.npz``, written by the worker (W: (2F, P) float64
    pixel positions, NaN where lost).
    """
    import cv2

    image = cv2.imread(str(first_frame), cv2.IMREAD_COLOR)
    if image is None:
        raise OSError(f"{first_frame.name} could not be read")
    with np.load(tracks_file, allow_pickle=False) as data:
        W = np.asarray(data["W"], dtype=np.float64)
    positions = W.reshape(-1, 2, W.shape[1]).transpose(2, 0, 1)  # (P, F, 2)
    seen_tracks = [track[np.isfinite(track[:, 0])] for track in positions]
    seen_tracks = [seen for seen in seen_tracks if len(seen)]
    ends = [np.round(seen[-1]).astype(np.int32) for seen in seen_tracks]
    starts = np.array([seen[0] for seen in seen_tracks]).reshape(-1, 2)
    paths = [
        np.round(seen_tracks[index]).astype(np.int32).reshape(-1, 1, 2)
        for index in _spread_out(starts, PATH_SPACING)
        if len(seen_tracks[index]) > 1
    ]
    cv2.polylines(image, paths, isClosed=False, color=_PATH_BGR, thickness=1, lineType=cv2.LINE_AA)
    for x, y in ends:
        image[max(y, 0) : y + 1, max(x, 0) : x + 1] = _END_BGR
    ok, encoded = cv2.imencode(".png", image)
    if not ok:
        raise OSError("OpenCV could not encode the overlay")
    return encoded.tobytes()
