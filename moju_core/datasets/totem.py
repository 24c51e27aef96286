"""Loader of the four real ToTem sequences (paper, T-shirt, hulk, cushion) and their scoring.

The data are the ``Data/`` folder of ``agnivsen/ToTem-NRSfM`` (Sengupta and Bartoli, IJCV
2024): perspective photographs of a deforming object with tracked pixel points, the ground
truth 3D points in each image's camera frame, the intrinsics ``K`` and the per-image depths of
two published methods (Chhatkuli et al.'s maximum-depth heuristic, MDH, and Ji et al.'s
maximum rigidity, MaxRig). The loader takes the directory as an argument, since a machine
(e.g. CI) may not have it; nothing here is downloaded.

Scoring follows the data's README (the paper's Eq. 17 with a per-image scale):
:func:`scaled_e3d` centres each image, scales the estimate to the truth's Frobenius norm,
aligns it by orthogonal Procrustes and averages ``||S_est - S_gt||_F / ||S_gt||_F``.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from moju_core.metrics import align, center_frames
from moju_core.priors.dense_depth import homogeneous

__all__ = [
    "TOTEM_NAMES",
    "TotemSequence",
    "load_totem",
    "out_of_plane_ratio",
    "pixels_to_rays",
    "scaled_e3d",
]

#: The four sequences, in the order of the published tables.
TOTEM_NAMES: tuple[str, ...] = ("kinectPaper", "whiteCartoonTshirt", "hulk", "cushion")


@dataclass(frozen=True)
class TotemSequence:
    """One real sequence with its ground truth and reference reconstructions.

    Attributes
    ----------
    name : str
        One of :data:`TOTEM_NAMES`.
    pixels : ndarray of shape (F, P, 2), float64
        Tracked image points in pixels, NaN where not seen.
    visibility : ndarray of shape (F, P), bool
        True where the point is seen.
    K : ndarray of shape (3, 3), float64
        Camera intrinsics (pixels).
    rays : ndarray of shape (F, P, 2), float64
        Normalised image coordinates ``inv(K) [u, v, 1]`` (first two entries), NaN where unseen.
    truth : ndarray of shape (F, P, 3), float64
        Ground-truth points in each image's camera frame (the scene unit, e.g. mm).
    reference_depths : dict of str to ndarray of shape (F, P)
        Per-image depths of the published methods, keys ``"MDH"`` and ``"MaxRig"``.
    """

    name: str
    pixels: np.ndarray
    visibility: np.ndarray
    K: np.ndarray
    rays: np.ndarray
    truth: np.ndarray
    reference_depths: dict[str, np.ndarray]

    def reference_shapes(self, method: str) -> np.ndarray:
        """The 3D points of a reference, ``depth * [x', y', 1]``, shape (F, P, 3)."""
        return depths_to_shapes(self.reference_depths[method], self.rays)


def _read_intrinsics(path: Path) -> np.ndarray:
    # The files mix comma- and space-separated rows (and one lacks its final newline).
    values = [float(v) for v in re.split(r"[,\s]+", path.read_text().strip()) if v]
    if len(values) != 9:
        raise ValueError(f"{path} must hold 9 numbers (a 3x3 K), found {len(values)}")
    return np.asarray(values, dtype=np.float64).reshape(3, 3)


def pixels_to_rays(pixels: np.ndarray, K: np.ndarray) -> np.ndarray:
    """Normalised image coordinates of pixel points.

    Parameters
    ----------
    pixels : ndarray of shape (..., 2)
        Pixel coordinates ``(u, v)``; NaN stays NaN.
    K : ndarray of shape (3, 3)
        Intrinsics (upper triangular, ``K[2] = [0, 0, 1]``).

    Returns
    -------
    rays : ndarray of shape (..., 2)
        ``(x', y')`` with ``inv(K) [u, v, 1] = [x', y', 1]`` (dimensionless).
    """
    pixels = np.asarray(pixels, dtype=np.float64)
    normalised = homogeneous(pixels) @ np.linalg.inv(np.asarray(K, dtype=np.float64)).T
    return normalised[..., :2] / normalised[..., 2:3]


def depths_to_shapes(depths: np.ndarray, rays: np.ndarray) -> np.ndarray:
    """Back-project depths along rays: ``depth * [x', y', 1]``, shape (F, P, 3)."""
    depths = np.asarray(depths, dtype=np.float64)
    rays = np.asarray(rays, dtype=np.float64)
    return depths[..., None] * homogeneous(rays)


def load_totem(directory: str | Path, name: str) -> TotemSequence:
    """Load one ToTem sequence.

    Parameters
    ----------
    directory : str or Path
        Folder holding ``data_<name>.mat``, ``intrinsics_<name>.txt`` and
        ``<name>_Initialisation.mat``.
    name : str
        One of :data:`TOTEM_NAMES`.

    Returns
    -------
    TotemSequence

    Raises
    ------
    FileNotFoundError
        If a file is missing.
    """
    from scipy.io import loadmat  # scipy.io is slow to import; only the loader needs it

    directory = Path(directory)
    data = loadmat(directory / f"data_{name}.mat", squeeze_me=True, struct_as_record=False)
    images = np.atleast_1d(data["p"])
    truths = np.atleast_1d(data["Pgth"])
    pixels = np.stack([np.asarray(im.p, dtype=np.float64)[:2].T for im in images])
    truth = np.stack([np.asarray(t.P, dtype=np.float64).T for t in truths])
    visibility = np.asarray(data["v"], dtype=bool).reshape(pixels.shape[:2])
    pixels = np.where(visibility[..., None], pixels, np.nan)
    K = _read_intrinsics(directory / f"intrinsics_{name}.txt")
    rays = pixels_to_rays(pixels, K)

    init = loadmat(
        directory / f"{name}_Initialisation.mat", squeeze_me=True, struct_as_record=False
    )["initialisations"]
    references = {}
    for key, field in (("MDH", "MDH_SOCP"), ("MaxRig", "MLH_SDP")):
        depth_list = np.atleast_1d(getattr(init, field).initialDepth)
        references[key] = np.stack([np.asarray(d, dtype=np.float64).ravel() for d in depth_list])
    return TotemSequence(name, pixels, visibility, K, rays, truth, references)


def _scaled_aligned(estimate: np.ndarray, truth: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Centre both, scale each estimated frame to the truth's norm, Procrustes-align."""
    estimate = center_frames(estimate)
    truth = center_frames(truth)
    est_norm = np.linalg.norm(estimate.reshape(len(estimate), -1), axis=1)
    true_norm = np.linalg.norm(truth.reshape(len(truth), -1), axis=1)
    scaled = estimate * (true_norm / np.maximum(est_norm, 1e-300))[:, None, None]
    return align(scaled, truth, "procrustes"), truth


def scaled_e3d(estimate: np.ndarray, truth: np.ndarray) -> float:
    """e3D with a per-image scale (the data README's rule; dimensionless).

    Parameters
    ----------
    estimate, truth : ndarray of shape (F, P, 3)
        Reconstructed and true points (any units each).

    Returns
    -------
    float
        Mean over images of ``||s_f S_est^f Q_f - S_gt^f||_F / ||S_gt^f||_F`` (centred,
        ``s_f`` matching the norms, ``Q_f`` orthogonal Procrustes).
    """
    aligned, truth = _scaled_aligned(estimate, truth)
    errors = np.linalg.norm((aligned - truth).reshape(len(truth), -1), axis=1)
    return float(np.mean(errors / np.linalg.norm(truth.reshape(len(truth), -1), axis=1)))


def out_of_plane_ratio(estimate: np.ndarray, truth: np.ndarray) -> float:
    """Out-of-plane extent recovered: mean over frames of ``sigma_3(aligned) / sigma_3(truth)``.

    ``sigma_3`` is the smallest singular value of a centred ``(P, 3)`` frame; the estimate is
    scaled and aligned as in :func:`scaled_e3d`. 1 means the depth relief is fully recovered,
    0 a flat estimate.
    """
    aligned, truth = _scaled_aligned(estimate, truth)
    s_est = np.linalg.svd(aligned, compute_uv=False)[:, -1]
    s_true = np.linalg.svd(truth, compute_uv=False)[:, -1]
    return float(np.mean(s_est / s_true))
