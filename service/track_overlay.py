"""The first frame of a video job with its tracks drawn on it, for the web page.

Every track is drawn as its path over the frames (the positions where it was followed, in
pixels of the frame) in green, ending in a dot where it was last seen: where the paths stop
early, the tracker lost the point.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

_PATH_BGR = (80, 220, 80)
_END_BGR = (40, 40, 240)


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
    paths, ends = [], []
    for track in positions:
        seen = track[np.isfinite(track[:, 0])]
        if len(seen) > 1:
            paths.append(np.round(seen).astype(np.int32).reshape(-1, 1, 2))
        if len(seen):
            ends.append(np.round(seen[-1]).astype(np.int32))
    cv2.polylines(image, paths, isClosed=False, color=_PATH_BGR, thickness=1, lineType=cv2.LINE_AA)
    for x, y in ends:
        image[max(y, 0) : y + 1, max(x, 0) : x + 1] = _END_BGR
    ok, encoded = cv2.imencode(".png", image)
    if not ok:
        raise OSError("OpenCV could not encode the overlay")
    return encoded.tobytes()
