"""The solve plan: every decision the solver takes from the data, in one printable record.

:func:`moju_core.reconstruct` decides, from what it measures on the tracks (their noise, the
completion of hidden entries and whether it is exact, where the cameras come from, the
temporal prior's weight), how the loop fits them. Those decisions are taken in one place,
:func:`make_plan`, and recorded as a frozen :class:`SolvePlan` in
:attr:`moju_core.result.Diagnostics.plan`, so that a reader can see why a solve ran as it did.
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Literal

from moju_core.defaults import EXACT_DATA_NOISE, MIN_DEPTH_PRIOR

#: How hidden entries were completed: nothing hidden, an exact low-rank model, or an
#: approximate one.
Completion = Literal["none", "exact", "approximate"]
#: The loop's data term (:mod:`moju_core.loop.data_terms`).
DataTermName = Literal[
    "soft", "banded-prior", "exact", "masked-exact", "anchored", "trajectory-basis"
]


@dataclass(frozen=True)
class SolvePlan:
    """How one solve fits its tracks.

    Attributes
    ----------
    method : str
        ``"moju"``, ``"sdg"``, ``"bmm"`` or ``"pta"``.
    n_frames, n_points : int
        F and P.
    observed_fraction : float
        Observed (frame, point) entries over F P.
    noise : float
        Noise variance of the scale-normalised tracks (relative to their mean square).
    completion : {"none", "exact", "approximate"}
        How hidden entries were completed.
    camera_source : str
        Where the rotations come from (``"known"`` or the estimator's name).
    rotation_smoothing : float
        Weight of the smoother that took frame-to-frame jitter out of given rotations
        (:func:`moju_core.cameras.smoothing.smooth_rotations`); 0 when used as given.
    refine_rotations : bool
        Whether the loop re-fits the rotations to the shapes.
    smoothness : float
        The temporal prior's weight.
    signal_fit : bool
        Whether noisy tracks were projected onto their signal subspace and fitted exactly.
    data_term : str
        The loop's data term (:data:`DataTermName`).
    camera_model : {"orthographic", "perspective"}
        Perspective when the camera's intrinsics were given and the surface prior used them.
    surface_prior : {"none", "isometric"}
        The surface prior the loop started from and was anchored to
        (:mod:`moju_core.perspective`).
    focal_px : float or None
        The perspective solve's focal length in pixels; None for an orthographic solve.
    focal_origin : {"given", "focal", "default", "estimated"} or None
        Where that focal length came from (:attr:`moju_core.cameras.intrinsics.Intrinsics.
        origin`): ``"estimated"`` when the camera was the default of the frame size and the
        tracks preferred another focal length (:mod:`moju_core.priors.focal_length`),
        ``"default"`` when they did not.
    """

    method: str
    n_frames: int
    n_points: int
    observed_fraction: float
    noise: float
    completion: Completion
    camera_source: str
    refine_rotations: bool
    smoothness: float
    signal_fit: bool
    data_term: DataTermName
    camera_model: Literal["orthographic", "perspective"] = "orthographic"
    surface_prior: Literal["none", "isometric"] = "none"
    rotation_smoothing: float = 0.0
    focal_px: float | None = None
    focal_origin: str | None = None

    def __str__(self) -> str:
        return "\n".join(f"{field.name}: {getattr(self, field.name)}" for field in fields(self))


def exact_data(noise: float, completion: Completion, camera_source: str) -> bool:
    """Whether the tracks are precise enough to be fitted exactly.

    Noise at most :data:`~moju_core.defaults.EXACT_DATA_NOISE`; with hidden entries and
    estimated cameras, only from an exact completion: an exact fit trusts the cameras, and
    those estimated from an approximate completion are degrees off, an error the exact fit
    would put into the depths.
    """
    if noise > EXACT_DATA_NOISE:
        return False
    return completion != "approximate" or camera_source == "known"


def tries_signal_fit(
    method: str, noise: float, camera_source: str, weight: float, exact_weight: float
) -> bool:
    """Whether the solve tries the exact fit of the projected tracks
    (:mod:`moju_core.priors.signal_fit`).

    Noisy tracks, known cameras, a local-model method (moju, sdg), a soft rule that chose a
    weight of at most the depth-setting one, and an exact rule on the same trials
    (``exact_weight``) that accepts the depth-setting weight. Estimated cameras are left out:
    an exact fit trusts them.
    """
    return (
        method in ("moju", "sdg")
        and noise > EXACT_DATA_NOISE
        and camera_source == "known"
        and weight <= MIN_DEPTH_PRIOR
        and exact_weight >= MIN_DEPTH_PRIOR
    )


def data_term_name(
    method: str, exact: bool, masked: bool, refine_rotations: bool, smoothness: float
) -> DataTermName:
    """The loop's data term: exact (masked when hidden entries are fitted softly beside the
    measured ones), the banded prior for refined cameras with a prior, else soft."""
    if method == "pta":
        return "trajectory-basis"
    if exact:
        return "masked-exact" if masked else "exact"
    if refine_rotations and smoothness > 0:
        return "banded-prior"
    return "soft"
