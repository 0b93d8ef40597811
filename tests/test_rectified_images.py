"""Raw images rectified into an imported dataset's ``images/``: the image map agrees with the keypoints' own
rectification, the import writes the images the detections name where the export looks for them, and a
raw image of the wrong size skips its camera with the reason."""
import json
import shutil

import cv2
import numpy as np

from pedx_graph.cli import main
from pedx_graph.data.calib import read_calibrations
from pedx_graph.data.images import image_path, read_image, rectification_maps, rectify_image
from pedx_graph.data.labels2d import read_label2d
from pedx_graph.detections.openpose import read_openpose
from pedx_graph.detections.rectified_images import write_rectified_images
from pedx_graph.detections.review_sheets import image_stems, index_images
from pedx_graph.detections.undistort import distort, find_camera, raw_camera, undistort_rectify
from scene_fixtures import small_scene


def _raw_size(raw) -> tuple[int, int]:
    """(W, H) of a raw image centred on the raw K's principal point."""
    return int(round(2 * raw.raw_K[0, 2])), int(round(2 * raw.raw_K[1, 2]))


def _dot_centre(image: np.ndarray, near: np.ndarray, radius: int = 12) -> np.ndarray:
    """Intensity-weighted centre (u, v) of the bright pixels within ``radius`` of ``near``."""
    grey = image.astype(float).mean(axis=2) if image.ndim == 3 else image.astype(float)
    u0, v0 = (int(round(x)) for x in near)
    patch = grey[v0 - radius:v0 + radius + 1, u0 - radius:u0 + radius + 1]
    weights = np.clip(patch - 60.0, 0.0, None)
    assert weights.sum() > 0, f"no dot near {near}"
    vv, uu = np.mgrid[v0 - radius:v0 + radius + 1, u0 - radius:u0 + radius + 1]
    return np.array([(weights * uu).sum(), (weights * vv).sum()]) / weights.sum()


def _pedx_scene(tmp_path, frames=8):
    from pedx_graph.sim.config import pedx_rig_config

    config = pedx_rig_config()
    config.detections.formats = ("openpose_body25",)
    return small_scene(tmp_path / "scene", pedestrians=4, frames=frames, seed=3, config=config)


def test_a_rectified_image_puts_a_raw_dot_where_the_keypoint_rectification_puts_it(tmp_path):
    """The real rig's distortion: dots drawn at the raw pixels of rectified points spread over the image come
    out, in the rectified image, at those points (the map and ``undistort_rectify`` are one model)."""
    root = _pedx_scene(tmp_path, frames=2)
    calibrations = read_calibrations(root / "calib")
    pair = sorted(calibrations.values(), key=lambda c: c.name)[0]
    for side in ("left", "right"):
        raw = raw_camera(pair, side)
        assert raw is not None and np.any(raw.raw_D != 0)
        width, height = pair.image_size
        rect = np.array([[u, v] for u in np.linspace(0.1, 0.9, 5) * width for v in np.linspace(0.15, 0.85, 4) * height])
        raw_uv = distort(rect, raw)
        np.testing.assert_allclose(undistort_rectify(raw_uv, raw), rect, atol=1e-3)
        image = np.zeros((_raw_size(raw)[1], _raw_size(raw)[0], 3), np.uint8)
        for u, v in raw_uv:
            cv2.circle(image, (int(round(u * 16)), int(round(v * 16))), 3 * 16, (255, 255, 255), -1, cv2.LINE_AA,
                       shift=4)
        out = rectify_image(image, rectification_maps(raw, pair.image_size))
        assert out.shape[:2] == (height, width)
        found = np.array([_dot_centre(out, p) for p in rect])
        assert np.max(np.linalg.norm(found - rect, axis=1)) < 0.5, (found - rect)


def test_import_writes_the_named_images_rectified_where_the_export_reads_them(tmp_path, capsys):
    """Simulated detections on the real rig's raw images: a dot at one keypoint of each detection in its
    raw image lands, in the written rectified image, on that keypoint's rectified label; every image the
    detections name is written, and those of the frames a camera detected nobody in, found by name; a folder
    of images of the wrong size skips their cameras with the reason."""
    root = _pedx_scene(tmp_path)
    files = tmp_path / "openpose"
    shutil.copytree(root / "detections" / "openpose_body25", files)
    dropped = sorted(files.rglob("*_0000003_keypoints.json"))[0]
    dropped.unlink()                                 # a camera that detected nobody in frame 3
    calibrations = read_calibrations(root / "calib")
    detections = read_openpose(files)
    assert (dropped.parent.name, 3) not in {(d.camera, d.frame) for d in detections}
    raw_dir = tmp_path / "raw"
    images = {}
    for det in detections:
        if det.image not in images:
            calib, side = find_camera(calibrations, det.camera)
            width, height = _raw_size(raw_camera(calib, side))
            images[det.image] = (det.camera, np.zeros((height, width, 3), np.uint8))
        nose = det.image_uv[0]
        if np.all(np.isfinite(nose)):
            cv2.circle(images[det.image][1], (int(round(nose[0] * 16)), int(round(nose[1] * 16))), 3 * 16,
                       (255, 255, 255), -1, cv2.LINE_AA, shift=4)
    frames = range(min(d.frame for d in detections), max(d.frame for d in detections) + 1)
    for camera in {d.camera for d in detections}:   # the frames a camera detected nobody in have images too
        calib, side = find_camera(calibrations, camera)
        width, height = _raw_size(raw_camera(calib, side))
        for frame in frames:
            images.setdefault(f"{detections[0].sequence}_{camera}_{frame:07d}",
                              (camera, np.zeros((height, width, 3), np.uint8)))
    for stem, (camera, image) in images.items():
        (raw_dir / camera).mkdir(parents=True, exist_ok=True)
        cv2.imwrite(str(raw_dir / camera / f"{stem}.png"), image)
    out = tmp_path / "imported"
    assert main(["import", "openpose", str(files), "--keypoint-set", "body25", "--calib", str(root),
                 "--out", str(out), "--raw-images", str(raw_dir), "--workers", "2"]) == 0
    assert "images rectified into" in capsys.readouterr().out
    summary = json.loads((out / "import_summary.json").read_text())
    ((seq, record),) = summary["sequences"].items()
    named = {(d.camera, d.frame) for d in detections}
    # every camera has an image of every frame: those it detected nobody in are found by name
    assert record["images"]["without_image"] == 0
    assert record["images"]["written"] == len(images) == len(named) + record["images"]["found_by_name"]
    assert record["images"]["found_by_name"] > 0
    named = {(camera, int(stem[-7:])) for stem, (camera, _) in images.items()}
    assert not record["images"]["skipped_cameras"] and len(record["images"]["rectified_cameras"]) == 4
    for camera, frame in named:
        written = read_image(image_path(out, seq, camera, frame))
        calib, _ = find_camera(calibrations, camera)
        assert written is not None and written.shape[:2] == tuple(calib.image_size)[::-1]
    checked = 0
    for path in sorted((out / "labels" / "2d").rglob("*.json")):
        seq_name, camera, frame, tid = path.stem.split("_", 3)
        label = read_label2d(path, seq_name, camera, int(frame), tid)
        nose = label.view.keypoints[0]
        if not np.all(np.isfinite(nose)):
            continue
        written = read_image(image_path(out, seq, label.camera, label.frame))
        near = np.linalg.norm(np.array([d.image_uv[0] for d in detections if (d.camera, d.frame) ==
                                        (label.camera, label.frame) and np.all(np.isfinite(d.image_uv[0]))])
                              - distort(nose[None], raw_camera(*find_camera(calibrations, label.camera))),
                              axis=1)
        if np.sum(near < 40) != 1:               # another person's dot close by: not a clean check
            continue
        assert np.linalg.norm(_dot_centre(written, nose) - nose) < 1.0
        checked += 1
    assert checked >= 10
    # raw images of the wrong size (a downscaled copy): the cameras are skipped with the reason
    small = tmp_path / "small"
    for stem, (camera, _) in images.items():
        (small / camera).mkdir(parents=True, exist_ok=True)
        cv2.imwrite(str(small / camera / f"{stem}.jpg"), np.zeros((60, 300, 3), np.uint8))
    skipped = write_rectified_images(tmp_path / "again", seq, image_stems(detections), index_images(small),
                                     calibrations)
    assert sorted(skipped["skipped_cameras"]) == sorted({camera for camera, _ in images.values()})
    assert all("principal point" in reason for reason in skipped["skipped_cameras"].values())
    assert skipped["written"] == 0 and not (tmp_path / "again" / "images").exists()
