"""Small shared helpers: atomic writes, image encoding, seeded random generators, JSON conversion."""
from __future__ import annotations

import json
import os
import secrets
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np


@contextmanager
def atomic_writer(path: str | os.PathLike) -> Iterator[BinaryIO]:
    """A binary file handle whose content replaces ``path`` atomically when the block ends without an
    exception (temporary file in the same folder, then rename; removed on any failure).

    The file gets the usual permissions (0666 less the process umask), as ``open`` would give it: the
    temporary file is created with ``O_EXCL`` under a random name and mode 0666 (the kernel applies the
    umask; ``tempfile.mkstemp`` would give 0600 whatever the umask)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    flags = os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_BINARY", 0)
    for _ in range(100):
        tmp = path.parent / f".{path.name}.{os.getpid()}.{secrets.token_hex(6)}.tmp"
        try:
            fd = os.open(tmp, flags, 0o666)
            break
        except FileExistsError:
            continue
    else:  # pragma: no cover -- 100 collisions of 48 random bits
        raise FileExistsError(f"{path.parent}: could not create a temporary file")
    try:
        with os.fdopen(fd, "wb") as fh:
            yield fh
        os.replace(tmp, path)
    except BaseException:
        if os.path.lexists(tmp):
            os.unlink(tmp)
        raise


def atomic_write_bytes(path: str | os.PathLike, data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically (:func:`atomic_writer`: temporary file, then rename)."""
    with atomic_writer(path) as fh:
        fh.write(data)
    return Path(path)


#: JPEG quality of the images the project writes (overlays, review sheets).
JPEG_QUALITY = 90


def encode_image(image: np.ndarray, ext: str) -> bytes:
    """``image`` (BGR) encoded as ``ext`` (".jpg" at ``JPEG_QUALITY``, ".png"); OSError when OpenCV cannot."""
    import cv2

    params = [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY] if ext == ".jpg" else []
    ok, buf = cv2.imencode(ext, image, params)
    if not ok:
        raise OSError(f"OpenCV could not encode a {ext} image")
    return buf.tobytes()


def to_jsonable(obj: Any) -> Any:
    """Convert numpy arrays/scalars (recursively) into plain JSON types."""
    if isinstance(obj, dict):
        return {str(k): to_jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [to_jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return to_jsonable(obj.tolist())
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, float) and not np.isfinite(obj):
        return None
    if isinstance(obj, Path):
        return str(obj)
    return obj


def atomic_write_json(path: str | os.PathLike, obj: Any, indent: int | None = 1) -> Path:
    """Write ``obj`` as JSON (numpy converted, non-finite floats as null) atomically."""
    text = json.dumps(to_jsonable(obj), indent=indent, sort_keys=False)
    return atomic_write_bytes(path, (text + "\n").encode("utf-8"))


def atomic_write_text(path: str | os.PathLike, text: str) -> Path:
    """Write a text file atomically (UTF-8)."""
    return atomic_write_bytes(path, text.encode("utf-8"))


def make_rng(seed: int | np.random.Generator | None) -> np.random.Generator:
    """A numpy Generator from a seed (or pass a Generator through). ``None`` is refused: runs are seeded."""
    if isinstance(seed, np.random.Generator):
        return seed
    if seed is None:
        raise ValueError("a seed is required (runs are reproducible)")
    return np.random.default_rng(int(seed))
