"""Rendered videos of a surface seen by a pinhole camera, with exact ground truth.

The sibling of :mod:`moju_core.footage.render` (whose rasteriser, textures, shading and
downsampling it uses) for shapes given in a camera's frame (metres, x right, y down, z > 0
forward) and a camera matrix :class:`moju_core.cameras.intrinsics.Intrinsics`:

* vertices are projected with K, ``pixel = K [x/z, y/z, 1]``;
* the z-buffer compares inverse depths ``1 / z``, which are affine in the image within a
  planar triangle, so the nearest surface is found exactly;
* the rasteriser's barycentric weights are screen-space; the surface weights of a pixel are
  the perspective-correct ``(w_i / z_i) / sum_j (w_j / z_j)``: texture coordinates (u, v) are
  interpolated with them, so the texture is fixed to the surface, not to the image;
* frames are rendered ``supersample`` times larger and box-filtered down; the texture has
  about two texels per output pixel across the surface's largest extent in the video.

Ground truth: every first-frame pixel centre the front of the surface covers names a surface
point, a triangle and its surface (perspective-correct) weights. A perspective projection is
not affine, so the same weights on the projected vertices would be wrong in other frames: the
point's 3D position in every frame is the weights on that frame's 3D vertices (``paths_3d``),
and its image position is the projection of that position (``paths_2d``), exact for the
rendered (piecewise-planar) mesh. ``visible`` says whether the point faces the camera and is
the nearest surface under its (rounded) image position: its depth is within
``_DEPTH_TOLERANCE`` (relative) of the z-buffer's there, or the z-buffer's triangle is its own.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from moju_core.cameras.intrinsics import Intrinsics
from moju_core.footage.render import (
    RenderedVideo,
    _downsample,
    _front_facing,
    _shade,
    _texture,
    rasterize,
)

__all__ = ["PerspectiveVideo", "project", "render_perspective", "surface_weights"]

# Relative depth tolerance of the visibility test: a point further than the z-buffer's
# surface by more than this fraction of its depth is hidden. One pixel of a surface seen at
# 80 degrees of slant spans about 0.6 % of its depth at f = 768 px and 0.75 m; the layers of a
# curl or a fold are centimetres (several %) apart.
_DEPTH_TOLERANCE = 0.01
# Texels per output pixel across the surface's largest extent (as render.py's texture).
_TEXELS_PER_PIXEL = 2.0


@dataclass(frozen=True, eq=False)
class PerspectiveVideo(RenderedVideo):
    """A :class:`RenderedVideo` of shapes in a pinhole camera's frame.

    ``rotations`` are identities (the shapes are in the camera frame already), ``scale`` is
    the focal length ``fx`` (pixels per metre at 1 m depth), ``paths_3d`` are in metres in
    the camera frame.

    Attributes
    ----------
    intrinsics : Intrinsics
        The camera that rendered it.
    """

    intrinsics: Intrinsics | None = None


def project(points: np.ndarray, K: np.ndarray) -> np.ndarray:
    """Pixels (..., 2) of camera-frame points (..., 3) (z > 0) through K (3, 3)."""
    image = points @ np.asarray(K).T
    return image[..., :2] / image[..., 2:3]


def surface_weights(
    triangle: np.ndarray, weights: np.ndarray, faces: np.ndarray, inverse_depth: np.ndarray
) -> np.ndarray:
    """Perspective-correct weights of rasterised pixels.

    Parameters
    ----------
    triangle : ndarray of shape (...,), int64
        Triangle under each pixel, -1 for none.
    weights : ndarray of shape (..., 3), float64
        Screen-space barycentric weights of the pixel centre in that triangle.
    faces : ndarray of shape (M, 3), int64
        Triangles.
    inverse_depth : ndarray of shape (V,), float64
        ``1 / z`` of every vertex (1 / metres).

    Returns
    -------
    weights : ndarray of shape (..., 3), float64
        Weights of the 3D vertices whose combination is the surface point under the pixel
        centre, ``(w_i / z_i) / sum_j (w_j / z_j)`` (0 where no triangle).
    """
    covered = triangle >= 0
    out = np.zeros_like(weights)
    scaled = weights[covered] * inverse_depth[faces[triangle[covered]]]
    out[covered] = scaled / scaled.sum(axis=-1, keepdims=True)
    return out


def _texture_size(pixels: np.ndarray, limit: int) -> int:
    """Texture side: _TEXELS_PER_PIXEL x the largest image extent of the surface, (F, V, 2)."""
    extent = np.max(pixels.max(axis=1) - pixels.min(axis=1))
    return int(np.clip(np.ceil(_TEXELS_PER_PIXEL * extent), 64, limit))


def _check_inputs(shapes: np.ndarray, faces: np.ndarray, uv: np.ndarray, size: tuple) -> None:
    if shapes.ndim != 3 or shapes.shape[2] != 3 or shapes.shape[0] < 2:
        raise ValueError(f"shapes must be (F >= 2, V, 3), got {shapes.shape}")
    if not np.all(shapes[..., 2] > 0):
        raise ValueError("every vertex must be in front of the camera (z > 0)")
    if uv.shape != (shapes.shape[1], 2) or faces.ndim != 2 or faces.shape[1] != 3:
        raise ValueError(f"uv must be (V, 2) and faces (M, 3), got {uv.shape}, {faces.shape}")
    for label, value in zip(("width", "height"), size, strict=True):
        if int(value) != value or value < 16:
            raise ValueError(f"{label} must be an integer >= 16, got {value!r}")


def render_perspective(
    shapes: np.ndarray,
    faces: np.ndarray,
    uv: np.ndarray,
    camera: Intrinsics,
    *,
    width: int = 640,
    height: int = 480,
    supersample: int = 2,
    seed: int = 0,
    name: str = "scene",
) -> PerspectiveVideo:
    """Render a textured mesh moving in a pinhole camera's frame, with its ground truth.

    Parameters
    ----------
    shapes : ndarray of shape (F, V, 3), float64
        Vertices in the camera frame in every frame, metres (z > 0).
    faces : ndarray of shape (M, 3), int64
        Triangles; counter-clockwise in the image (y down) is the front.
    uv : ndarray of shape (V, 2), float64
        Texture coordinates in [0, 1].
    camera : Intrinsics
        The pinhole camera (K in pixels).
    width, height : int, default 640, 480
        Frame size in pixels.
    supersample : int, default 2
        Frames are rasterised this many times larger and box-filtered down (1..4).
    seed : int, default 0
        Seed of the texture.
    name : str, default "scene"
        Name recorded in the video.

    Returns
    -------
    video : PerspectiveVideo
    """
    shapes, uv = np.asarray(shapes, dtype=np.float64), np.asarray(uv, dtype=np.float64)
    _check_inputs(shapes, faces, uv, (width, height))
    if int(supersample) != supersample or not 1 <= supersample <= 4:
        raise ValueError(f"supersample must be an integer in 1..4, got {supersample!r}")
    pixels = project(shapes, camera.K)
    inverse_depth = 1.0 / shapes[..., 2]
    rng = np.random.default_rng([seed, 11])
    size = _texture_size(pixels, 4 * max(width, height))
    textures = (_texture(size, rng, bright=True), _texture(size, rng, False))
    n_frames, k = shapes.shape[0], supersample
    frames = np.empty((n_frames, height, width, 3), dtype=np.uint8)
    points: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
    visible = np.zeros(0)
    for f in range(n_frames):
        front = _front_facing(pixels[f], faces)
        fine = k * pixels[f] + 0.5 * (k - 1)  # output centre i = mean of fine k i .. k i + k - 1
        tri, weights, _ = rasterize(fine, inverse_depth[f], faces, k * height, k * width)
        weights = surface_weights(tri, weights, faces, inverse_depth[f])
        image = _downsample(_shade(tri, weights, faces, uv, front, textures), k)
        frames[f] = np.clip(np.rint(image * 255.0), 0, 255).astype(np.uint8)
        buffers = rasterize(pixels[f], inverse_depth[f], faces, height, width)
        if points is None:
            points = _first_frame_points(buffers, front, faces, inverse_depth[0])
            visible = np.zeros((n_frames, points[0].size), dtype=bool)
        visible[f] = _visible(shapes[f], camera.K, buffers, front, faces, points)
    assert points is not None
    return _video(name, frames, shapes, faces, camera, points, visible)


def _first_frame_points(
    buffers: tuple[np.ndarray, np.ndarray, np.ndarray],
    front: np.ndarray,
    faces: np.ndarray,
    inverse_depth: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The surface points under the first frame's covered front pixel centres.

    Returns the pixel indices (N,) into the flattened (H, W) frame, their triangles (N,) and
    surface weights (N, 3).
    """
    triangle, weights, _ = buffers
    keep = triangle >= 0
    keep[keep] = front[triangle[keep]]
    pixel = np.flatnonzero(keep)
    tri = triangle.ravel()[pixel]
    bary = surface_weights(tri, weights.reshape(-1, 3)[pixel], faces, inverse_depth)
    return pixel, tri, bary


def _visible(
    shape: np.ndarray,
    K: np.ndarray,
    buffers: tuple[np.ndarray, np.ndarray, np.ndarray],
    front: np.ndarray,
    faces: np.ndarray,
    points: tuple[np.ndarray, np.ndarray, np.ndarray],
) -> np.ndarray:
    """(N,) bool: the points face the camera and are the nearest surface in this frame."""
    triangle, _, zbuffer = buffers
    height, width = triangle.shape
    _, tri, bary = points
    position = np.einsum("nk,nkd->nd", bary, shape[faces[tri]])
    xy = np.rint(project(position, K)).astype(np.int64)
    inside = (xy[:, 0] >= 0) & (xy[:, 0] < width) & (xy[:, 1] >= 0) & (xy[:, 1] < height)
    x, y = np.where(inside, xy[:, 0], 0), np.where(inside, xy[:, 1], 0)
    nearest = zbuffer[y, x]  # inverse depth of the nearest surface there, -inf for none
    own = triangle[y, x] == tri
    close = 1.0 / position[:, 2] >= nearest / (1.0 + _DEPTH_TOLERANCE)
    return inside & front[tri] & (own | close)


def _video(
    name: str,
    frames: np.ndarray,
    shapes: np.ndarray,
    faces: np.ndarray,
    camera: Intrinsics,
    points: tuple[np.ndarray, np.ndarray, np.ndarray],
    visible: np.ndarray,
) -> PerspectiveVideo:
    """Assemble the video and the ground truth of the first frame's surface points."""
    pixel, tri, bary = points
    n_frames, height, width = frames.shape[:3]
    paths_3d = np.einsum("nk,fnkd->fnd", bary, shapes[:, faces[tri]])
    pixel_index = np.full(height * width, -1, dtype=np.int64)
    pixel_index[pixel] = np.arange(pixel.size)
    return PerspectiveVideo(
        name=name,
        frames=frames,
        rotations=np.broadcast_to(np.eye(3), (n_frames, 3, 3)).copy(),
        scale=camera.fx,
        pixel_index=pixel_index.reshape(height, width),
        points_xy=np.stack([pixel % width, pixel // width], axis=1).astype(np.int64),
        paths_2d=project(paths_3d, camera.K),
        paths_3d=paths_3d,
        visible=visible,
        intrinsics=camera,
    )
