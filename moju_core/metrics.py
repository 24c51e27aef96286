"""Accuracy measures for reconstructions: the 3D error of the paper's Eq. 17 and a camera
rotation error.

Orthographic NRSfM recovers shapes only up to one global rotation and a reflection (and each
frame's translation is lost with the image centroid), so every measure here states the
alignment it applies before comparing:

* ``"procrustes"``: each frame gets its own orthogonal 3x3 transform (reflections allowed, no
  scaling). This is what published tables, including the paper's Table 1, report.
* ``"global"``: one orthogonal 3x3 transform for the whole sequence (reflection allowed, no
  scaling). Stricter: a per-frame flip or twist of the estimate is not forgiven.
* ``"sign"``: no rotation at all, only centring and the better of the two depth signs
  (``z -> -z``) chosen once for the whole sequence. Meaningful when the estimate is expressed
  in the same world frame as the truth (e.g. solved with known rotations).

All shapes are arrays of shape ``(F, P, 3)``: frame, point, coordinate.

With missing data (a visibility mask, ``(F, P)`` bool, True = observed), :func:`e3d_occluded`
measures the error over the entries the solver had to fill in; the alignment is still fitted
over every point of a frame, as for :func:`e3d`.
"""

from __future__ import annotations

from typing import Literal

import numpy as np

from moju_core.cameras.refinement import project_to_stiefel

Alignment = Literal["procrustes", "global", "sign"]
ALIGNMENTS: tuple[str, ...] = ("procrustes", "global", "sign")


def _check_pair(
    estimate: np.ndarray, truth: np.ndarray, names: tuple[str, str], layout: str, tail: tuple
) -> tuple[np.ndarray, np.ndarray]:
    """Convert both to float64 and check that they are matching finite 3-D ``layout`` stacks."""
    estimate = np.asarray(estimate, dtype=np.float64)
    truth = np.asarray(truth, dtype=np.float64)
    if truth.ndim != 3 or truth.shape[3 - len(tail) :] != tail:
        raise ValueError(f"{names[1]} must have shape {layout}, got {truth.shape}")
    if estimate.shape != truth.shape:
        raise ValueError(
            f"{names[0]} and {names[1]} must have the same shape {layout}, "
            f"got {names[0]} {estimate.shape} and {names[1]} {truth.shape}"
        )
    if not (np.all(np.isfinite(estimate)) and np.all(np.isfinite(truth))):
        raise ValueError(f"{names[0]} and {names[1]} must be finite (found NaN or inf)")
    return estimate, truth


def _check_shapes(estimate: np.ndarray, truth: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    return _check_pair(estimate, truth, ("estimate", "truth"), "(F, P, 3)", (3,))


def _check_rotations(R_est: np.ndarray, R_true: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    return _check_pair(R_est, R_true, ("R_est", "R_true"), "(F, 2, 3)", (2, 3))


def center_frames(shapes: np.ndarray) -> np.ndarray:
    """Subtract each frame's centroid.

    Parameters
    ----------
    shapes : ndarray of shape (F, P, 3), float64
        Per-frame 3D points (any length unit).

    Returns
    -------
    centred : ndarray of shape (F, P, 3), float64
        A new array; every frame has zero mean over its points.
    """
    shapes = np.asarray(shapes, dtype=np.float64)
    if shapes.ndim != 3 or shapes.shape[2] != 3:
        raise ValueError(f"shapes must have shape (F, P, 3), got {shapes.shape}")
    return shapes - shapes.mean(axis=1, keepdims=True)


def _relative_errors(estimate: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """Per-frame ``||S_est^f - S_gt^f||_F / ||S_gt^f||_F`` of already aligned stacks, (F,)."""
    truth_norms = np.linalg.norm(truth.reshape(truth.shape[0], -1), axis=1)
    if np.any(truth_norms == 0.0):
        frames = np.flatnonzero(truth_norms == 0.0)
        raise ValueError(
            f"ground-truth frames {frames.tolist()} collapse to a single point after centring; "
            "the relative error is undefined"
        )
    differences = (estimate - truth).reshape(truth.shape[0], -1)
    return np.linalg.norm(differences, axis=1) / truth_norms


def align(estimate: np.ndarray, truth: np.ndarray, mode: Alignment = "procrustes") -> np.ndarray:
    """Align an estimated shape sequence to the ground truth.

    Both sequences are centred per frame first (orthographic cameras lose translation).

    Parameters
    ----------
    estimate : ndarray of shape (F, P, 3), float64
        Reconstructed shapes.
    truth : ndarray of shape (F, P, 3), float64
        Ground-truth shapes, same points in the same order.
    mode : {"procrustes", "global", "sign"}, default "procrustes"
        ``"procrustes"``: per frame the orthogonal ``Q_f`` minimising
        ``||S_est^f Q_f - S_gt^f||_F``; ``"global"``: one orthogonal ``Q`` minimising
        ``sum_f ||S_est^f Q - S_gt^f||_F^2``; ``"sign"``: the estimate or its depth-mirrored
        copy (``z -> -z``), whichever has the smaller mean relative error. No scaling in any
        mode; reflections are allowed in all.

    Returns
    -------
    aligned : ndarray of shape (F, P, 3), float64
        The centred, aligned estimate (same units as the input).

    Raises
    ------
    ValueError
        If the shapes differ or are not ``(F, P, 3)``, or ``mode`` is unknown.
    """
    estimate, truth = _check_shapes(estimate, truth)
    estimate = center_frames(estimate)
    truth = center_frames(truth)
    if mode == "procrustes":
        # Cross-covariances of all frames at once, (F, 3, 3); one batched SVD.
        covariances = np.einsum("fpi,fpj->fij", estimate, truth)
        return estimate @ project_to_stiefel(covariances)
    if mode == "global":
        covariance = np.einsum("fpi,fpj->ij", estimate, truth)
        return estimate @ project_to_stiefel(covariance)
    if mode == "sign":
        mirrored = estimate * np.array([1.0, 1.0, -1.0])
        if _relative_errors(mirrored, truth).mean() < _relative_errors(estimate, truth).mean():
            return mirrored
        return estimate
    raise ValueError(f"mode must be one of {ALIGNMENTS}, got {mode!r}")


def e3d(estimate: np.ndarray, truth: np.ndarray, alignment: Alignment = "procrustes") -> float:
    """Mean relative 3D error of the paper's Eq. 17.

    ``e3D = (1/F) sum_f ||S_est^f - S_gt^f||_F / ||S_gt^f||_F`` after centring and the
    chosen alignment (see :func:`align`).

    Parameters
    ----------
    estimate : ndarray of shape (F, P, 3), float64
        Reconstructed shapes.
    truth : ndarray of shape (F, P, 3), float64
        Ground-truth shapes.
    alignment : {"procrustes", "global", "sign"}, default "procrustes"
        How the estimate is aligned before comparison.

    Returns
    -------
    error : float
        Dimensionless; 0 for a perfect reconstruction.
    """
    aligned = align(estimate, truth, alignment)
    return float(_relative_errors(aligned, center_frames(truth)).mean())


def _check_visibility(visibility: np.ndarray, truth: np.ndarray) -> np.ndarray:
    visibility = np.asarray(visibility)
    if visibility.dtype != bool or visibility.shape != truth.shape[:2]:
        raise ValueError(
            f"visibility must be a bool array of shape (F, P) = {truth.shape[:2]}, got "
            f"{visibility.dtype} {visibility.shape}"
        )
    return visibility


def _occluded_errors(aligned: np.ndarray, truth: np.ndarray, occluded: np.ndarray) -> np.ndarray:
    """Per-frame relative error over the occluded points of the frames that have any, (F',)."""
    frames = np.flatnonzero(occluded.any(axis=1))
    mask = occluded[frames, :, None]
    truth_norms = np.sqrt(np.sum(np.where(mask, truth[frames], 0.0) ** 2, axis=(1, 2)))
    if np.any(truth_norms == 0.0):
        zero = frames[truth_norms == 0.0]
        raise ValueError(
            f"the occluded ground-truth points of frames {zero.tolist()} all lie at the frame's "
            "centroid; their relative error is undefined"
        )
    differences = np.where(mask, aligned[frames] - truth[frames], 0.0)
    return np.sqrt(np.sum(differences**2, axis=(1, 2))) / truth_norms


def e3d_occluded(
    estimate: np.ndarray,
    truth: np.ndarray,
    visibility: np.ndarray,
    alignment: Alignment = "procrustes",
) -> float:
    """Mean relative 3D error over the unobserved (frame, point) entries only.

    The estimate is centred and aligned exactly as by :func:`e3d` (over every point of each
    frame); then, for each frame ``f`` with at least one unobserved point (set ``O_f``),
    ``||S_est^f[O_f] - S_gt^f[O_f]||_F / ||S_gt^f[O_f]||_F`` with the ground truth centred
    over all its points. The mean is over those frames; frames without unobserved points are
    skipped.

    Parameters
    ----------
    estimate : ndarray of shape (F, P, 3), float64
        Reconstructed shapes (every point in every frame).
    truth : ndarray of shape (F, P, 3), float64
        Ground-truth shapes.
    visibility : ndarray of shape (F, P), bool
        True where the point was observed by the solver.
    alignment : {"procrustes", "global", "sign"}, default "procrustes"
        How the estimate is aligned before comparison.

    Returns
    -------
    error : float
        Dimensionless; 0 when the filled-in points are exact.

    Raises
    ------
    ValueError
        When ``visibility`` does not fit or marks every entry as observed.
    """
    estimate, truth = _check_shapes(estimate, truth)
    occluded = ~_check_visibility(visibility, truth)
    if not occluded.any():
        raise ValueError("visibility marks every entry as observed: nothing is occluded")
    aligned = align(estimate, truth, alignment)
    return float(_occluded_errors(aligned, center_frames(truth), occluded).mean())


def rigid_approximation(shapes: np.ndarray, n_iter: int = 20) -> np.ndarray:
    """Best single rigid shape for a whole sequence (generalised orthogonal Procrustes).

    Alternates between aligning every centred frame to the current mean shape (per-frame
    orthogonal Procrustes) and re-averaging, starting from the first frame. The e3D of the
    returned sequence measures how far a sequence is from rigid: a rigid reconstruction can
    never do better than that.

    Parameters
    ----------
    shapes : ndarray of shape (F, P, 3), float64
        Ground-truth (or any) shape sequence.
    n_iter : int, default 20
        Number of align-and-average rounds.

    Returns
    -------
    rigid : ndarray of shape (F, P, 3), float64
        The Procrustes mean shape (centred) repeated for every frame.
    """
    centred = center_frames(shapes)
    mean_shape = centred[0]
    for _ in range(n_iter):
        covariances = np.einsum("fpi,pj->fij", centred, mean_shape)
        aligned = centred @ project_to_stiefel(covariances)
        mean_shape = aligned.mean(axis=0)
    return np.broadcast_to(mean_shape, centred.shape).copy()


def _complete_rotations(rows: np.ndarray) -> np.ndarray:
    """Complete 2x3 camera rows to proper 3x3 rotations, (F, 2, 3) -> (F, 3, 3).

    The rows are first replaced by the nearest pair of orthonormal rows (polar factor), so
    slightly non-orthonormal estimates are still compared as rotations; the third row is
    their cross product, which makes the determinant +1.
    """
    orthonormal = project_to_stiefel(rows)
    third = np.cross(orthonormal[:, 0], orthonormal[:, 1])
    return np.concatenate([orthonormal, third[:, None, :]], axis=1)


def rotation_errors_deg(R_est: np.ndarray, R_true: np.ndarray) -> np.ndarray:
    """Per-frame camera rotation error in degrees after one global alignment.

    One orthogonal 3x3 ``Q`` (reflection allowed) minimises ``||R_est - R_true Q||_F`` over
    the stacked 2F x 3 rows of all frames; it absorbs the global rotation/reflection
    ambiguity of NRSfM. Then ``R_est^f`` and ``R_true^f Q`` are completed to proper 3x3
    rotations ``A_f``, ``B_f`` and the geodesic angle
    ``arccos((trace(A_f^T B_f) - 1) / 2)`` is returned (evaluated in a form that stays
    accurate near 0 and 180 degrees).

    Parameters
    ----------
    R_est : ndarray of shape (F, 2, 3), float64
        Estimated camera rotations (rows approximately orthonormal).
    R_true : ndarray of shape (F, 2, 3), float64
        True camera rotations.

    Returns
    -------
    errors : ndarray of shape (F,), float64
        Angles in degrees, in [0, 180].
    """
    R_est, R_true = _check_rotations(R_est, R_true)
    stacked_est = R_est.reshape(-1, 3)
    stacked_true = R_true.reshape(-1, 3)
    Q = project_to_stiefel(stacked_true.T @ stacked_est)
    A = _complete_rotations(R_est)
    B = _complete_rotations(R_true @ Q)
    traces = np.einsum("fij,fij->f", A, B)
    # Same angle as arccos((trace - 1) / 2), but arccos loses half the digits near 0 (an
    # exact match would read ~1e-6 degrees); use sin(theta/2) = ||A - B||_F / sqrt(8) and
    # cos(theta/2) = sqrt((trace + 1) / 4), both clipped against rounding.
    sin_half = np.clip(np.linalg.norm(A - B, axis=(1, 2)) / np.sqrt(8.0), 0.0, 1.0)
    cos_half = np.sqrt(np.clip((traces + 1.0) / 4.0, 0.0, 1.0))
    return np.degrees(2.0 * np.arctan2(sin_half, cos_half))


def rotation_error_deg(R_est: np.ndarray, R_true: np.ndarray) -> float:
    """Mean camera rotation error in degrees; see :func:`rotation_errors_deg`.

    Parameters
    ----------
    R_est : ndarray of shape (F, 2, 3), float64
        Estimated camera rotations.
    R_true : ndarray of shape (F, 2, 3), float64
        True camera rotations.

    Returns
    -------
    error : float
        Mean geodesic angle over frames, degrees.
    """
    return float(rotation_errors_deg(R_est, R_true).mean())


def evaluate(
    estimate: np.ndarray,
    truth: np.ndarray,
    R_est: np.ndarray | None = None,
    R_true: np.ndarray | None = None,
    visibility: np.ndarray | None = None,
) -> dict[str, float]:
    """All accuracy measures of a reconstruction in one dictionary.

    Parameters
    ----------
    estimate : ndarray of shape (F, P, 3), float64
        Reconstructed shapes.
    truth : ndarray of shape (F, P, 3), float64
        Ground-truth shapes.
    R_est : ndarray of shape (F, 2, 3), float64, optional
        Estimated camera rotations.
    R_true : ndarray of shape (F, 2, 3), float64, optional
        True camera rotations.
    visibility : ndarray of shape (F, P), bool, optional
        The observations the solver used (True = observed).

    Returns
    -------
    scores : dict of str to float
        ``e3d_procrustes``, ``e3d_global``, ``e3d_sign`` (dimensionless, over all points);
        when ``visibility`` has unobserved entries, ``observed_fraction`` and
        ``e3d_occluded_procrustes``, ``e3d_occluded_global``, ``e3d_occluded_sign``
        (:func:`e3d_occluded`); when both rotation stacks are given, ``rotation_error_deg``
        (degrees).
    """
    estimate, truth = _check_shapes(estimate, truth)
    if (R_est is None) != (R_true is None):
        raise ValueError("give both R_est and R_true, or neither")
    occluded = None if visibility is None else ~_check_visibility(visibility, truth)
    if occluded is not None and not occluded.any():
        occluded = None
    centred_truth = center_frames(truth)
    scores = {}
    for mode in ALIGNMENTS:
        aligned = align(estimate, truth, mode)
        scores[f"e3d_{mode}"] = float(_relative_errors(aligned, centred_truth).mean())
        if occluded is not None:
            errors = _occluded_errors(aligned, centred_truth, occluded)
            scores[f"e3d_occluded_{mode}"] = float(errors.mean())
    if occluded is not None:
        scores["observed_fraction"] = float(1.0 - occluded.mean())
    if R_est is not None and R_true is not None:
        R_est, R_true = _check_rotations(R_est, R_true)
        if R_true.shape[0] != truth.shape[0]:
            raise ValueError(
                f"rotations cover {R_true.shape[0]} frames but shapes cover {truth.shape[0]}"
            )
        scores["rotation_error_deg"] = rotation_error_deg(R_est, R_true)
    return scores
