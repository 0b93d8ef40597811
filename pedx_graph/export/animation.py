"""An animated GIF (or, where this OpenCV cannot encode GIF, an MP4) of a track from its frames' pictures.

:func:`compose` puts a frame's pictures side by side at one height (the overlay crop around the person and
the top view with that frame marked); :func:`write_animation` encodes the frames with OpenCV's animation
encoder (``cv2.imencodeanimation``, GIF, looping) and writes the file atomically; without that encoder the
frames go to an MP4 through ``cv2.VideoWriter`` (``mp4v``) beside it.
"""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from pedx_graph.utils import atomic_write_bytes

#: Height of an animation frame, pixels.
FRAME_HEIGHT_PX = 360


def fit_height(image: np.ndarray, height: int) -> np.ndarray:
    """``image`` resized to ``height`` pixels, aspect kept."""
    import cv2

    width = max(1, int(round(image.shape[1] * height / image.shape[0])))
    return cv2.resize(image, (width, height), interpolation=cv2.INTER_AREA)


def compose(pictures: list[np.ndarray], height: int = FRAME_HEIGHT_PX) -> np.ndarray:
    """The pictures resized to one height and put side by side with a 4 px white gap."""
    parts = []
    for picture in pictures:
        if parts:
            parts.append(np.full((height, 4, 3), 255, np.uint8))
        parts.append(fit_height(picture, height))
    return np.concatenate(parts, axis=1)


def _same_size(frames: list[np.ndarray]) -> list[np.ndarray]:
    """Frames padded (white, right and bottom) to the largest width and height."""
    height = max(f.shape[0] for f in frames)
    width = max(f.shape[1] for f in frames)
    out = []
    for f in frames:
        canvas = np.full((height, width, 3), 255, np.uint8)
        canvas[:f.shape[0], :f.shape[1]] = f
        out.append(canvas)
    return out


def write_animation(path: str | os.PathLike, frames: list[np.ndarray], fps: float = 5.0) -> Path:
    """Write ``frames`` (BGR uint8) as a looping GIF at ``path`` (``.gif``); returns the path written, which is
    ``path`` with ``.mp4`` when this OpenCV has no GIF encoder."""
    import cv2

    if not frames:
        raise ValueError(f"{path}: no frame to animate")
    frames = _same_size(frames)
    path = Path(path)
    if hasattr(cv2, "imencodeanimation"):
        animation = cv2.Animation()
        animation.frames = frames
        animation.durations = [int(round(1000 / fps))] * len(frames)
        animation.loop_count = 0
        ok, buf = cv2.imencodeanimation(".gif", animation)
        if ok:
            return atomic_write_bytes(path.with_suffix(".gif"), buf.tobytes())
    return _write_mp4(path.with_suffix(".mp4"), frames, fps)


def _write_mp4(path: Path, frames: list[np.ndarray], fps: float) -> Path:
    import cv2

    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.parent / f".{path.name}.{os.getpid()}.tmp.mp4"
    height, width = frames[0].shape[:2]
    writer = cv2.VideoWriter(str(tmp), cv2.VideoWriter_fourcc(*"mp4v"), fps, (width, height))
    try:
        if not writer.isOpened():
            raise OSError(f"{path}: OpenCV can encode neither GIF nor MP4 here")
        for frame in frames:
            writer.write(frame)
    finally:
        writer.release()
    os.replace(tmp, path)
    return path
