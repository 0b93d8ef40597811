"""simulate --images: rendered images at the requested size, the true bodies where the calibration projects
them, the same bytes on a re-run, and none without the flag."""
from __future__ import annotations

import cv2
import numpy as np

from pedx_graph.body import BodyModel
from pedx_graph.cli import main
from pedx_graph.data.calib import read_calibrations
from pedx_graph.data.reader import read_smpl_labels
from pedx_graph.export.camera import dataset_cameras
from pedx_graph.sim.config import SimConfig
from scene_fixtures import small_scene, tree_digest


def test_images_show_the_true_bodies_where_the_calibration_projects_them(tmp_path):
    config = SimConfig()
    config.images.enabled = True
    config.images.scale = 0.25
    scene = small_scene(tmp_path / "scene", 3, 2, seed=0, config=config)
    cameras = dataset_cameras(read_calibrations(scene / "calib"))
    truth = read_smpl_labels(scene)
    model = BodyModel.load()
    checked = 0
    for (seq, tid), labels in truth.items():
        for lab in labels:
            verts = model.forward(lab.pose, lab.betas, lab.trans).vertices
            for name, camera in cameras.items():
                path = scene / "images" / seq / name / f"{seq}_{name}_{lab.frame:07d}.jpg"
                image = cv2.imread(str(path))
                width, height = camera.image_size
                assert image.shape == (round(height * 0.25), round(width * 0.25), 3)
                uv, depth = camera.project(verts, 0.25)
                inside = (depth > 1) & (uv[:, 0] >= 1) & (uv[:, 1] >= 1) & (uv[:, 0] < image.shape[1] - 1) & \
                    (uv[:, 1] < image.shape[0] - 1)
                if inside.mean() < 0.99:
                    continue
                # the body's pixels are saturated colours; the ground and sky around it are near-grey
                hsv = cv2.cvtColor(image, cv2.COLOR_BGR2HSV)
                centre = np.median(uv[inside], axis=0).round().astype(int)
                box = hsv[max(centre[1] - 1, 0):centre[1] + 2, max(centre[0] - 1, 0):centre[0] + 2, 1]
                lo = np.floor(uv[inside].min(axis=0)).astype(int) - 6
                ring = hsv[max(lo[1], 0):max(lo[1], 0) + 3, max(lo[0], 0):max(lo[0], 0) + 3, 1]
                if box.size and ring.size:
                    assert box.max() > 80 and ring.mean() < 80
                    checked += 1
    assert checked > 0


def test_cli_flag_writes_identical_images_and_none_without_it(tmp_path):
    for name in ("a", "b"):
        assert main(["simulate", str(tmp_path / name), "--pedestrians", "1", "--frames", "2", "--images",
                     "--image-scale", "0.1", "--seed", "2"]) == 0
    images = tree_digest(tmp_path / "a" / "images")
    assert len(images) == 8 and images == tree_digest(tmp_path / "b" / "images")
    assert main(["simulate", str(tmp_path / "c"), "--pedestrians", "1", "--frames", "2", "--seed", "2"]) == 0
    assert not (tmp_path / "c" / "images").exists()
