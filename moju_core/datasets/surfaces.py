"""Surface building blocks of the generators: parameter grids and their meshes, smooth
bumps and signals, inextensible bending, colour ramps.
"""

from __future__ import annotations

import numpy as np


def parameter_grid(n_points: int, aspect: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The first ``n_points`` of a row-major grid over the unit square, and its triangles.

    The grid has about ``aspect`` times more columns than rows, so cells are nearly square
    on a surface ``aspect`` times wider than tall; its last row may be partial.

    Returns
    -------
    u, v : ndarray of shape (P,), float64
        Column and row coordinates in [0, 1].
    faces : ndarray of shape (M, 3), int64
        Two triangles per grid cell, kept when all three corners exist.
    """
    n_cols = max(2, round(np.sqrt(n_points * aspect)))
    # At least two rows, so that even tiny grids are not collinear.
    n_cols = min(n_cols, n_points // 2)
    n_rows = -(-n_points // n_cols)
    index = np.arange(n_points)
    u = (index % n_cols) / (n_cols - 1)
    v = (index // n_cols) / (n_rows - 1)

    rows, cols = np.meshgrid(np.arange(n_rows - 1), np.arange(n_cols - 1), indexing="ij")
    corner = (rows * n_cols + cols).ravel()
    lower = np.stack([corner, corner + 1, corner + n_cols], axis=1)
    upper = np.stack([corner + 1, corner + n_cols + 1, corner + n_cols], axis=1)
    triangles = np.concatenate([lower, upper])
    faces = triangles[triangles.max(axis=1) < n_points]
    return u, v, faces.astype(np.int64)


def gaussian(
    x: np.ndarray, y: np.ndarray, cx: float, cy: float, sx: float, sy: float
) -> np.ndarray:
    """Axis-aligned anisotropic Gaussian bump of height 1 centred at (cx, cy), (P,)."""
    return np.exp(-0.5 * (((x - cx) / sx) ** 2 + ((y - cy) / sy) ** 2))


def sigmoid(values: np.ndarray) -> np.ndarray:
    return 0.5 * (1.0 + np.tanh(0.5 * values))


def smooth_signals(
    rng: np.random.Generator, times: np.ndarray, n_signals: int, cycles: tuple[float, float]
) -> np.ndarray:
    """Smooth random signals spanning [-1, 1]: sums of two sinusoids, random frequencies.

    Parameters
    ----------
    times : ndarray of shape (F,)
        Normalised time in [0, 1].
    cycles : (float, float)
        Range of the frequencies, in cycles per sequence.

    Returns
    -------
    signals : ndarray of shape (F, n_signals), float64
    """
    frequencies = rng.uniform(*cycles, size=(2, n_signals))
    phases = rng.uniform(0.0, 2.0 * np.pi, size=(2, n_signals))
    amplitudes = rng.uniform(0.5, 1.0, size=(2, n_signals))
    waves = amplitudes * np.sin(2.0 * np.pi * frequencies * times[:, None, None] + phases)
    signals = waves.sum(axis=1)
    # Stretch every signal to span [-1, 1] exactly, so that every expression reaches full
    # activation whatever the seed and the sequence length.
    low, high = signals.min(axis=0), signals.max(axis=0)
    span = np.where(high > low, high - low, 1.0)
    return 2.0 * (signals - low) / span - 1.0


def cumulative_trapezoid(values: np.ndarray, step: float) -> np.ndarray:
    """Running integral along the last axis on a uniform grid, starting at 0, same shape."""
    integral = np.zeros_like(values)
    integral[..., 1:] = np.cumsum(0.5 * step * (values[..., 1:] + values[..., :-1]), axis=-1)
    return integral


def bend_sheet(curvature: np.ndarray, step: float, u: np.ndarray) -> np.ndarray:
    """Points of an inextensible plane curve with the given curvature, by arc length.

    Integrates ``theta = int kappa ds``, ``x = int cos(theta) ds``, ``z = int sin(theta) ds``
    on the samples, then interpolates every frame's curve linearly at the points' arc
    lengths (the weights are shared by all frames because the samples are).

    Parameters
    ----------
    curvature : ndarray of shape (F, K), float64
        Curvature (1 / object units) on K uniform arc-length samples, ``step`` apart.
    step : float
        Sample spacing (object units); the curve's length is ``(K - 1) * step``.
    u : ndarray of shape (P,)
        The points' arc lengths as fractions of the curve's length, in [0, 1].

    Returns
    -------
    curve : ndarray of shape (F, P, 2), float64
        In-plane (x) and out-of-plane (z) coordinates, starting at the origin along +x.
    """
    n_samples = curvature.shape[1]
    tangent_angle = cumulative_trapezoid(curvature, step)
    curve_x = cumulative_trapezoid(np.cos(tangent_angle), step)
    curve_z = cumulative_trapezoid(np.sin(tangent_angle), step)
    position = u * (n_samples - 1)
    left = np.minimum(position.astype(np.int64), n_samples - 2)
    fraction = position - left
    return np.stack(
        [c[:, left] * (1.0 - fraction) + c[:, left + 1] * fraction for c in (curve_x, curve_z)],
        axis=-1,
    )


def ramp_colors(values: np.ndarray, low: tuple[int, int, int], high: tuple[int, int, int]):
    """Linear colour ramp between two RGB colours over the range of ``values``, (P, 3) uint8."""
    span = np.ptp(values)
    weights = (values - values.min()) / span if span > 0 else np.zeros_like(values)
    colors = np.asarray(low) + weights[:, None] * (np.asarray(high) - np.asarray(low))
    return np.round(colors).astype(np.uint8)
