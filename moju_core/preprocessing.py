"""Pre-processing of the measurements: translation removal and scale normalisation."""

from __future__ import annotations

import numpy as np


def normalise(W: np.ndarray) -> tuple[np.ndarray, float]:
    """Centre every row of W and divide by the RMS of the result.

    Under an orthographic camera the image of the object's centroid is the mean of each
    frame's x and y rows, so subtracting row means removes the per-frame translation. Dividing
    by the RMS makes the default weights independent of pixel units; the solver multiplies the
    output shapes by the returned scale.

    Parameters
    ----------
    W : ndarray of shape (2F, P), float64

    Returns
    -------
    centred : ndarray of shape (2F, P)
        Row means zero, RMS one (unless W is constant, then all zeros).
    scale : float
        The RMS divided out (1.0 for a constant W).
    """
    centred = W - W.mean(axis=1, keepdims=True)
    rms = float(np.sqrt(np.mean(centred**2)))
    scale = rms if rms > 0 else 1.0
    return centred / scale, scale
