"""Rendered videos of the synthetic deforming surfaces, with the ground truth to score tracks.

A sequence of :mod:`moju_core.datasets` (a sheet of paper, a cloth, a face) is rendered as a
textured triangle mesh (the sequence's parameter grid, two triangles per cell) under a moving
orthographic camera:

* the texture is procedural noise at several scales, defined on the surface's (u, v)
  parameter square, so that it moves with the surface and has detail at every scale optical
  flow looks at; the back of the surface carries a second, darker texture;
* rasterisation is vectorised numpy: every triangle's pixel centres inside its bounding box are
  tested with barycentric coordinates and a z-buffer keeps the nearest surface (no holes on a
  connected mesh, since adjacent triangles share their edges exactly);
* frames are rendered ``supersample`` times larger and box-filtered down, which anti-aliases
  silhouettes and texture;
* the background is uniform.

The ground truth is built at the output resolution: every pixel centre of the first frame that
the front of the surface covers names a surface point (a triangle and barycentric weights);
since an orthographic projection is affine, the same weights on the projected vertices give the
point's exact image position in every frame (``paths_2d``), and on the 3D vertices its 3D
position (``paths_3d``). ``visible`` says whether the point is the nearest surface under its
image position and faces the camera.

Image coordinates are pixels, x to the right, y down, pixel centres at integers (the top-left
pixel's centre is (0, 0)), as :mod:`moju_core.footage.tracking` writes them.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.ndimage import gaussian_filter, map_coordinates
from scipy.spatial.transform import Rotation

# The grid layout of the sequences' points (one definition, in datasets).
from moju_core.datasets import make_sequence
from moju_core.datasets.surfaces import parameter_grid

__all__ = [
    "VIDEO_CODECS",
    "RenderedVideo",
    "TrackScores",
    "rasterize",
    "render_sequence",
    "score_tracks",
    "write_image_folder",
    "write_video",
]

#: FourCC used by :func:`write_video` for each container (what OpenCV's FFmpeg backend in the
#: ``opencv-python-headless`` wheels can encode).
VIDEO_CODECS = {".mp4": "mp4v", ".avi": "MJPG", ".webm": "VP80"}

_BACKGROUND = (40, 40, 48)
# Margin left around the surface's bounding box over all frames, as a fraction of the frame.
_MARGIN = 0.06
# Depth tolerance of the visibility test (object units; sheets are about 2 long): a point
# behind the z-buffer by more than this is occluded. Layers of a rolled sheet are much further
# apart, neighbouring pixels of one smooth surface much closer.
_DEPTH_TOLERANCE = 0.03
# Texture noise scales, in texels; the texture has about two texels per output pixel across
# the frame, so the finest scale is about one pixel.
_TEXTURE_SIGMAS = (2.0, 4.0, 8.0, 16.0)
# Candidate pixels tested at once by the rasteriser (memory bound of a chunk).
_CHUNK_CANDIDATES = 2_000_000


@dataclass(frozen=True, eq=False)
class RenderedVideo:
    """A rendered video of a deforming surface and its ground truth.

    Attributes
    ----------
    name : str
        Name of the rendered sequence (``"paper"``, ``"cloth"``, ``"face1"`` ...).
    frames : ndarray of shape (F, H, W, 3), uint8
        RGB frames.
    rotations : ndarray of shape (F, 3, 3), float64
        Camera rotations; rows 0 and 1 project to image x and y (y up), row 2 points to the
        camera.
    scale : float
        Pixels per object unit.
    pixel_index : ndarray of shape (H, W), int64
        Index into the ground-truth points of the surface point under each first-frame pixel
        centre, -1 where the front of the surface does not cover it.
    points_xy : ndarray of shape (N, 2), int64
        Pixel (x, y) of every ground-truth point in the first frame.
    paths_2d : ndarray of shape (F, N, 2), float64
        Image position (x, y) in pixels of every ground-truth point in every frame.
    paths_3d : ndarray of shape (F, N, 3), float64
        3D position in object units (the world frame of the sequence's shapes).
    visible : ndarray of shape (F, N), bool
        Whether the point faces the camera and is the nearest surface under its position.
    """

    name: str
    frames: np.ndarray
    rotations: np.ndarray
    scale: float
    pixel_index: np.ndarray
    points_xy: np.ndarray
    paths_2d: np.ndarray
    paths_3d: np.ndarray
    visible: np.ndarray

    @property
    def n_frames(self) -> int:
        """Number of frames F."""
        return int(self.frames.shape[0])

    @property
    def frame_size(self) -> tuple[int, int]:
        """(width, height) in pixels."""
        return int(self.frames.shape[2]), int(self.frames.shape[1])

    @property
    def mask(self) -> np.ndarray:
        """(H, W) bool: first-frame pixels on the front of the surface."""
        return self.pixel_index >= 0

    def lookup(self, xy: np.ndarray) -> np.ndarray:
        """Ground-truth point index of first-frame positions ``xy``.

        Parameters
        ----------
        xy : ndarray of shape (P, 2)
            First-frame (x, y) positions in pixels; rounded to the nearest pixel centre.

        Returns
        -------
        index : ndarray of shape (P,), int64
            Index into ``points_xy``, ``paths_2d`` ...; -1 off the surface or off the frame.
        """
        pixels = np.rint(np.asarray(xy, dtype=np.float64)).astype(np.int64)
        height, width = self.pixel_index.shape
        inside = (
            (pixels[:, 0] >= 0)
            & (pixels[:, 0] < width)
            & (pixels[:, 1] >= 0)
            & (pixels[:, 1] < height)
        )
        index = np.full(pixels.shape[0], -1, dtype=np.int64)
        index[inside] = self.pixel_index[pixels[inside, 1], pixels[inside, 0]]
        return index


# --- rasterisation -------------------------------------------------------------------------


def rasterize(
    vertices: np.ndarray, depth: np.ndarray, faces: np.ndarray, height: int, width: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Z-buffered rasterisation of a triangle mesh at pixel centres.

    Parameters
    ----------
    vertices : ndarray of shape (V, 2), float64
        Vertex (x, y) in pixels, y down, pixel centres at integers.
    depth : ndarray of shape (V,), float64
        Vertex depth, larger is nearer the camera.
    faces : ndarray of shape (M, 3), int64
        Triangles.
    height, width : int
        Image size in pixels.

    Returns
    -------
    triangle : ndarray of shape (H, W), int64
        The nearest triangle covering each pixel centre, -1 for none.
    weights : ndarray of shape (H, W, 3), float64
        Barycentric weights of the pixel centre in that triangle (0 where none).
    zbuffer : ndarray of shape (H, W), float64
        Depth of the nearest surface, -inf where none.
    """
    corners = vertices[faces]  # (M, 3, 2)
    low = np.maximum(np.ceil(corners.min(axis=1)), 0).astype(np.int64)
    high = np.minimum(np.floor(corners.max(axis=1)), [width - 1, height - 1]).astype(np.int64)
    extent = high - low + 1
    keep = np.all(extent > 0, axis=1)
    found: list[tuple[np.ndarray, ...]] = []
    for chunk in _chunks(np.flatnonzero(keep), extent):
        found.append(_rasterize_chunk(chunk, corners, depth[faces], low, extent, width))
    pixel, near, tri, bary = (
        np.concatenate([part[i] for part in found]) if found else np.zeros(0) for i in range(4)
    )
    triangle = np.full(height * width, -1, dtype=np.int64)
    weights = np.zeros((height * width, 3))
    zbuffer = np.full(height * width, -np.inf)
    if pixel.size:
        pixel = pixel.astype(np.int64)
        # Sorted by pixel, nearest first: the first entry of every pixel wins the z-test.
        order = np.lexsort((-near, pixel))
        first = np.ones(order.size, dtype=bool)
        first[1:] = pixel[order[1:]] != pixel[order[:-1]]
        winner = order[first]
        triangle[pixel[winner]] = tri[winner].astype(np.int64)
        weights[pixel[winner]] = bary.reshape(-1, 3)[winner]
        zbuffer[pixel[winner]] = near[winner]
    return (
        triangle.reshape(height, width),
        weights.reshape(height, width, 3),
        zbuffer.reshape(height, width),
    )


def _chunks(triangles: np.ndarray, extent: np.ndarray):
    """Groups of triangles whose padded bounding-box candidates fit in _CHUNK_CANDIDATES."""
    # Similar bounding boxes together, so a chunk's padding to its largest box stays small;
    # a chunk pads every box to its largest width and height, at most the largest side squared.
    box = extent[triangles].max(axis=1) ** 2
    order = np.argsort(box, kind="stable")
    triangles, box = triangles[order], box[order]
    start = 0
    while start < triangles.size:
        ends = np.arange(start + 1, triangles.size + 1)
        cost = (ends - start) * box[ends - 1]  # increasing: both factors grow
        end = start + max(1, int(np.searchsorted(cost, _CHUNK_CANDIDATES, side="right")))
        yield triangles[start:end]
        start = end


def _rasterize_chunk(
    chunk: np.ndarray,
    corners: np.ndarray,
    face_depth: np.ndarray,
    low: np.ndarray,
    extent: np.ndarray,
    width: int,
) -> tuple[np.ndarray, ...]:
    """Covered pixel centres of the triangles ``chunk``: (pixel, depth, triangle, weights)."""
    span_x, span_y = extent[chunk].max(axis=0)
    offset_y, offset_x = np.meshgrid(np.arange(span_y), np.arange(span_x), indexing="ij")
    offset_x, offset_y = offset_x.ravel(), offset_y.ravel()
    px = low[chunk, 0, None] + offset_x[None, :]
    py = low[chunk, 1, None] + offset_y[None, :]
    in_box = (offset_x[None, :] < extent[chunk, 0, None]) & (
        offset_y[None, :] < extent[chunk, 1, None]
    )
    a, b, c = (corners[chunk, k] for k in range(3))
    area = _edge(a, b, c[:, 0, None], c[:, 1, None])[:, 0]
    safe = np.where(np.abs(area) > 1e-12, area, np.inf)[:, None]
    w_a = _edge(b, c, px, py) / safe
    w_b = _edge(c, a, px, py) / safe
    w_c = 1.0 - w_a - w_b
    inside = in_box & (w_a >= -1e-9) & (w_b >= -1e-9) & (w_c >= -1e-9) & np.isfinite(safe)
    rows, cols = np.nonzero(inside)
    bary = np.stack([w_a[rows, cols], w_b[rows, cols], w_c[rows, cols]], axis=1)
    near = np.einsum("nk,nk->n", bary, face_depth[chunk[rows]])
    pixel = py[rows, cols] * width + px[rows, cols]
    return pixel, near, chunk[rows], bary.ravel()


def _edge(a: np.ndarray, b: np.ndarray, px: np.ndarray, py: np.ndarray) -> np.ndarray:
    """Edge function of the line a -> b at points (px, py); a, b (n, 2), px, py (n, k)."""
    return (b[:, 0, None] - a[:, 0, None]) * (py - a[:, 1, None]) - (
        b[:, 1, None] - a[:, 1, None]
    ) * (px - a[:, 0, None])


# --- scene ---------------------------------------------------------------------------------


def _camera_path(n_frames: int, range_deg: float, seed: int) -> np.ndarray:
    """Camera rotations ``Rz(roll) Rx(pitch) Ry(yaw)`` (F, 3, 3).

    Yaw sweeps once from -range to +range, pitch swings by a third of the range and roll by
    up to 4 degrees, with random phases: a hand-held camera moving around the object.
    """
    rng = np.random.default_rng([seed, 7])
    phases = rng.uniform(0.0, 2.0 * np.pi, size=2)
    times = np.linspace(0.0, 1.0, n_frames)
    yaw = -range_deg * np.cos(np.pi * times)
    pitch = range_deg / 3.0 * np.sin(2.0 * np.pi * 0.7 * times + phases[0])
    roll = min(4.0, range_deg / 6.0) * np.sin(2.0 * np.pi * 0.5 * times + phases[1])
    angles = np.stack([roll, pitch, yaw], axis=1)
    return Rotation.from_euler("ZXY", angles, degrees=True).as_matrix()


def _surface_uv(name: str, n_points: int) -> np.ndarray:
    """(P, 2) parameter coordinates (u, v) in [0, 1] of a sequence's points.

    The grids of :mod:`moju_core.datasets`: the face maps an aspect 1/1.3 grid onto an
    ellipse, the paper and the cloth use aspect 1.4.
    """
    aspect = 1.0 / 1.3 if name.startswith("face") else 1.4
    u, v, _ = parameter_grid(n_points, aspect=aspect)
    return np.stack([u, v], axis=1)


def _texture(size: int, rng: np.random.Generator, bright: bool) -> np.ndarray:
    """Multi-scale coloured noise, (size, size, 3) float32 in [0, 1]."""
    layers = np.zeros((size, size, 3))
    for sigma in _TEXTURE_SIGMAS:
        noise = gaussian_filter(rng.standard_normal((size, size, 3)), (sigma, sigma, 0))
        layers += noise / noise.std()
    layers /= layers.std()
    base = np.array([0.62, 0.55, 0.45]) if bright else np.array([0.30, 0.32, 0.38])
    contrast = 0.16 if bright else 0.08
    return np.clip(base + contrast * layers, 0.0, 1.0).astype(np.float32)


def _sample_texture(texture: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Bilinear samples of ``texture`` at parameter coordinates ``uv`` (n, 2), (n, 3)."""
    size = texture.shape[0]
    coords = np.clip(uv, 0.0, 1.0) * (size - 1)
    return np.stack(
        [
            map_coordinates(texture[:, :, k], [coords[:, 1], coords[:, 0]], order=1)
            for k in range(3)
        ],
        axis=1,
    )


def _projection(
    rotations: np.ndarray, shapes: np.ndarray, translations: np.ndarray, width: int, height: int
) -> tuple[np.ndarray, np.ndarray, float]:
    """Vertex pixels (F, V, 2) and depths (F, V), framed to fit all frames; and the scale."""
    image = np.einsum("fij,fvj->fvi", rotations[:, :2], shapes) + translations[:, None, :]
    depth = np.einsum("fj,fvj->fv", rotations[:, 2], shapes)
    low, high = image.reshape(-1, 2).min(axis=0), image.reshape(-1, 2).max(axis=0)
    span = np.maximum(high - low, 1e-9)
    scale = float(np.min((1.0 - 2.0 * _MARGIN) * np.array([width, height]) / span))
    centre = 0.5 * (low + high)
    pixels = np.empty_like(image)
    pixels[..., 0] = 0.5 * (width - 1) + scale * (image[..., 0] - centre[0])
    pixels[..., 1] = 0.5 * (height - 1) - scale * (image[..., 1] - centre[1])  # y down
    return pixels, depth * scale, scale


def _front_facing(pixels: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(M,) bool: triangles whose front (the +z side at rest) faces the camera.

    With y down in pixels a counter-clockwise (front) triangle has a negative signed area.
    """
    a, b, c = (pixels[faces[:, k]] for k in range(3))
    cross = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])
    return cross < 0


def _shade(
    triangle: np.ndarray,
    weights: np.ndarray,
    faces: np.ndarray,
    uv: np.ndarray,
    front: np.ndarray,
    textures: tuple[np.ndarray, np.ndarray],
) -> np.ndarray:
    """RGB float image (H, W, 3) in [0, 1] of a rasterised frame."""
    image = np.empty((*triangle.shape, 3), dtype=np.float64)
    image[:] = np.asarray(_BACKGROUND) / 255.0
    covered = triangle >= 0
    tri = triangle[covered]
    pixel_uv = np.einsum("nk,nkd->nd", weights[covered], uv[faces[tri]])
    is_front = front[tri]
    colours = np.empty((tri.size, 3))
    colours[is_front] = _sample_texture(textures[0], pixel_uv[is_front])
    colours[~is_front] = _sample_texture(textures[1], pixel_uv[~is_front])
    image[covered] = colours
    return image


def _downsample(image: np.ndarray, factor: int) -> np.ndarray:
    """Box filter and subsample by ``factor``: (kH, kW, 3) -> (H, W, 3)."""
    height, width = image.shape[0] // factor, image.shape[1] // factor
    blocks = image.reshape(height, factor, width, factor, 3)
    return blocks.mean(axis=(1, 3))


def render_sequence(
    name: str = "paper",
    *,
    width: int = 320,
    height: int = 240,
    n_frames: int = 40,
    camera_range_deg: float = 25.0,
    mesh_points: int | None = None,
    supersample: int = 2,
    seed: int = 0,
) -> RenderedVideo:
    """Render a synthetic sequence of :mod:`moju_core.datasets` into a video with ground truth.

    Parameters
    ----------
    name : str, default "paper"
        A sequence of :func:`moju_core.datasets.make_sequence` (``paper``, ``cloth``,
        ``face1`` ...); its deforming shapes are used, the camera is this module's.
    width, height : int, default 320, 240
        Frame size in pixels.
    n_frames : int, default 40
        Number of frames F (>= 2).
    camera_range_deg : float, default 25.0
        The camera yaws once from -range to +range degrees, with pitch and roll (see
        ``_camera_path``); the surface fills the frame over the whole sequence.
    mesh_points : int, optional
        Vertices of the mesh; by default about one per 8 pixels of the frame (triangles of a
        few pixels), at least 400.
    supersample : int, default 2
        Frames are rendered this many times larger and box-filtered down (anti-aliasing).
    seed : int, default 0
        Seed of the sequence, the camera phases and the texture.

    Returns
    -------
    video : RenderedVideo
    """
    for label, value, least in (("width", width, 16), ("height", height, 16)):
        if int(value) != value or value < least:
            raise ValueError(f"{label} must be an integer >= {least}, got {value!r}")
    if int(supersample) != supersample or not 1 <= supersample <= 4:
        raise ValueError(f"supersample must be an integer in 1..4, got {supersample!r}")
    if mesh_points is None:
        mesh_points = max(400, width * height // 8)
    sequence = make_sequence(name, n_frames=n_frames, n_points=mesh_points, seed=seed)
    faces = sequence.faces
    uv = _surface_uv(name, sequence.n_points)
    rotations = _camera_path(sequence.n_frames, camera_range_deg, seed)
    pixels, depth, scale = _projection(
        rotations, sequence.shapes, sequence.translations, width, height
    )
    rng = np.random.default_rng([seed, 11])
    texture_size = 2 * max(width, height)
    textures = (_texture(texture_size, rng, bright=True), _texture(texture_size, rng, False))

    frames = np.empty((sequence.n_frames, height, width, 3), dtype=np.uint8)
    k = supersample
    zbuffers = np.empty((sequence.n_frames, height, width))
    first: tuple[np.ndarray, np.ndarray] | None = None
    for f in range(sequence.n_frames):
        front = _front_facing(pixels[f], faces)
        # Output pixel centre i is the mean of supersampled centres k i + 0 .. k - 1.
        fine = k * pixels[f] + 0.5 * (k - 1)
        tri, weights, _ = rasterize(fine, depth[f] * k, faces, k * height, k * width)
        image = _downsample(_shade(tri, weights, faces, uv, front, textures), k)
        frames[f] = np.clip(np.rint(image * 255.0), 0, 255).astype(np.uint8)
        coarse_tri, coarse_weights, zbuffers[f] = rasterize(
            pixels[f], depth[f], faces, height, width
        )
        if f == 0:
            keep = coarse_tri >= 0
            keep[keep] = front[coarse_tri[keep]]
            first = (np.where(keep, coarse_tri, -1), coarse_weights)
    assert first is not None
    return _ground_truth(
        sequence.name,
        frames,
        rotations,
        scale,
        first,
        faces,
        pixels,
        depth,
        sequence.shapes,
        zbuffers,
    )


def _ground_truth(
    name: str,
    frames: np.ndarray,
    rotations: np.ndarray,
    scale: float,
    first: tuple[np.ndarray, np.ndarray],
    faces: np.ndarray,
    pixels: np.ndarray,
    depth: np.ndarray,
    shapes: np.ndarray,
    zbuffers: np.ndarray,
) -> RenderedVideo:
    """Paths and visibility of the surface points under the first frame's pixel centres."""
    triangle, weights = first
    height, width = triangle.shape
    rows, cols = np.nonzero(triangle >= 0)
    tri, bary = triangle[rows, cols], weights[rows, cols]
    corners = faces[tri]  # (N, 3)
    paths_2d = np.einsum("nk,fnkd->fnd", bary, pixels[:, corners])
    paths_3d = np.einsum("nk,fnkd->fnd", bary, shapes[:, corners])
    point_depth = np.einsum("nk,fnk->fn", bary, depth[:, corners])
    visible = np.zeros(point_depth.shape, dtype=bool)
    for f in range(frames.shape[0]):
        front = _front_facing(pixels[f], faces)[tri]
        x, y = (
            np.rint(paths_2d[f, :, 0]).astype(np.int64),
            np.rint(paths_2d[f, :, 1]).astype(np.int64),
        )
        inside = (x >= 0) & (x < width) & (y >= 0) & (y < height)
        nearest = np.full(x.shape, np.inf)
        nearest[inside] = zbuffers[f][y[inside], x[inside]]
        visible[f] = inside & front & (point_depth[f] >= nearest - _DEPTH_TOLERANCE * scale)
    pixel_index = np.full((height, width), -1, dtype=np.int64)
    pixel_index[rows, cols] = np.arange(rows.size)
    return RenderedVideo(
        name=name,
        frames=frames,
        rotations=rotations,
        scale=scale,
        pixel_index=pixel_index,
        points_xy=np.stack([cols, rows], axis=1).astype(np.int64),
        paths_2d=paths_2d,
        paths_3d=paths_3d,
        visible=visible,
    )


# --- output --------------------------------------------------------------------------------


def write_video(path: str | os.PathLike, frames: np.ndarray, fps: float = 10.0) -> Path:
    """Encode RGB ``frames`` (F, H, W, 3) uint8 with OpenCV; the codec follows the extension.

    ``.mp4`` (MPEG-4 part 2), ``.avi`` (Motion JPEG) or ``.webm`` (VP8); see
    :data:`VIDEO_CODECS`. Raises ValueError for another extension and OSError when OpenCV
    cannot open the writer.
    """
    import cv2

    path = Path(path)
    codec = VIDEO_CODECS.get(path.suffix.lower())
    if codec is None:
        raise ValueError(
            f"{path.name}: unknown video extension; use one of {', '.join(VIDEO_CODECS)}"
        )
    height, width = frames.shape[1:3]
    writer = cv2.VideoWriter(
        str(path), cv2.VideoWriter_fourcc(*codec), float(fps), (int(width), int(height))
    )
    if not writer.isOpened():
        raise OSError(f"OpenCV could not open a {codec} writer for {path.name}")
    try:
        writer.set(cv2.VIDEOWRITER_PROP_QUALITY, 100)
        for frame in frames:
            writer.write(np.ascontiguousarray(frame[:, :, ::-1]))  # OpenCV wants BGR
    finally:
        writer.release()
    return path


def write_image_folder(directory: str | os.PathLike, frames: np.ndarray) -> list[Path]:
    """Write RGB ``frames`` (F, H, W, 3) uint8 as ``frame_00000.png`` ... into ``directory``."""
    import cv2

    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    paths = []
    for f, frame in enumerate(frames):
        path = directory / f"frame_{f:05d}.png"
        if not cv2.imwrite(str(path), np.ascontiguousarray(frame[:, :, ::-1])):
            raise OSError(f"OpenCV could not write {path.name}")
        paths.append(path)
    return paths


# --- scoring -------------------------------------------------------------------------------


@dataclass(frozen=True)
class TrackScores:
    """Accuracy of 2D tracks against a rendered video's ground truth.

    Errors are endpoint errors in pixels over the kept track-frames after the first frame
    (where every track starts exactly on its grid point), against the true image position of
    the surface point the track started on, whether or not that point is visible there.

    Attributes
    ----------
    median_error, p90_error : float
        Median and 90th percentile endpoint error (pixels).
    fraction_kept : float
        Kept track-frames over all track-frames (F x P).
    fraction_of_visible_kept : float
        Kept track-frames among those where the ground truth says the point is visible.
    fraction_kept_occluded : float
        Kept track-frames where the ground truth says the point is hidden (ideally 0).
    n_tracks : int
        Tracks scored (those starting on the surface).
    n_off_surface : int
        Tracks starting off the front of the surface (not scored).
    """

    median_error: float
    p90_error: float
    fraction_kept: float
    fraction_of_visible_kept: float
    fraction_kept_occluded: float
    n_tracks: int
    n_off_surface: int


def score_tracks(video: RenderedVideo, W: np.ndarray) -> TrackScores:
    """Score tracks ``W`` (2F, P) float64 (NaN where lost, pixels) of ``video``.

    The tracks must cover the video's frames; each one is matched to the ground-truth point
    under its first-frame position (rounded to the nearest pixel centre).
    """
    n_frames = W.shape[0] // 2
    if W.shape[0] != 2 * n_frames or n_frames != video.n_frames:
        raise ValueError(f"W must have shape (2F, P) with F = {video.n_frames}, got {W.shape}")
    positions = W.reshape(n_frames, 2, -1).transpose(0, 2, 1)  # (F, P, 2)
    index = video.lookup(positions[0])
    on_surface = index >= 0
    positions = positions[:, on_surface]
    truth = video.paths_2d[:, index[on_surface]]
    visible = video.visible[:, index[on_surface]]
    kept = np.isfinite(positions[..., 0])
    errors = np.linalg.norm(positions[1:] - truth[1:], axis=2)[kept[1:]]
    if errors.size == 0:
        median = p90 = float("nan")
    else:
        median, p90 = (float(value) for value in np.percentile(errors, [50, 90]))
    return TrackScores(
        median_error=median,
        p90_error=p90,
        fraction_kept=float(kept.mean()) if kept.size else 0.0,
        fraction_of_visible_kept=float(kept[visible].mean()) if visible.any() else 0.0,
        fraction_kept_occluded=float((kept & ~visible).sum() / max(kept.sum(), 1)),
        n_tracks=int(on_surface.sum()),
        n_off_surface=int((~on_surface).sum()),
    )
