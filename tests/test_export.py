"""pedx-graph export: meshes where the results say, watertight with the model's vertex count; overlays of the
image's size (rendered images and blank canvas); top views and GIFs that decode; byte-identical re-runs."""
from __future__ import annotations

import io
import json

import cv2
import numpy as np
import pytest
import trimesh

from pedx_graph.body import BodyModel
from pedx_graph.cli import main
from pedx_graph.data.ground import GroundFrame
from pedx_graph.data.reader import read_dataset, read_smpl_labels
from pedx_graph.export.camera import Camera, dataset_cameras
from pedx_graph.export.meshes import level_T_lidar
from pedx_graph.export.run import ExportConfig, export_results
from pedx_graph.graph.config import FitConfig
from pedx_graph.sim.config import SimConfig
from pedx_graph.solvers.fit import fit_dataset
from scene_fixtures import small_scene, tree_digest


@pytest.fixture(scope="module")
def fitted(tmp_path_factory):
    """A 2 x 5 scene with rendered quarter-size images, fitted."""
    root = tmp_path_factory.mktemp("export")
    config = SimConfig()
    config.images.enabled = True
    config.images.scale = 0.25
    scene = small_scene(root / "scene", 2, 5, seed=3, config=config)
    results = root / "results"
    fit_dataset(scene, results, FitConfig(), workers=1)
    return scene, results


def test_meshes_have_the_model_vertices_are_watertight_and_lie_where_the_results_say(fitted, tmp_path):
    scene, results = fitted
    out = tmp_path / "out"
    record = export_results(results, out, scene, ExportConfig(overlays=False, animations=False))
    model = BodyModel.load()
    rest = trimesh.Trimesh(model.forward(np.zeros(72), np.zeros(10)).vertices, model.faces, process=False)
    labels = read_smpl_labels(results)
    assert record["files"]["meshes"] == 2 * sum(len(v) for v in labels.values())
    for (seq, tid), labs in labels.items():
        for lab in labs:
            for ext in ("ply", "obj"):
                path = out / "meshes" / seq / f"{seq}_{lab.frame:07d}_{tid}.{ext}"
                mesh = trimesh.load(io.BytesIO(path.read_bytes()), file_type=ext, process=False)
                assert len(mesh.vertices) == model.num_vertices
                assert mesh.is_watertight == rest.is_watertight
                # the exported vertices reproduce the results' keypoints through the model's keypoint map
                joints = model.keypoint_map.apply(np.asarray(mesh.vertices)[None, model.keypoint_map.vertex_ids],
                                                  model.forward(lab.pose, lab.betas, lab.trans).joints[None])[0]
                kp = np.asarray(lab.extra["keypoints_3d"])
                assert np.abs(joints - kp).max() < (1e-4 if ext == "ply" else 2e-3)
                assert np.linalg.norm(np.asarray(mesh.vertices).mean(axis=0) - kp.mean(axis=0)) < 0.4
    assert rest.is_watertight


def test_world_frame_meshes_stand_on_the_derived_ground(fitted, tmp_path):
    scene, results = fitted
    out = tmp_path / "out"
    export_results(results, out, scene, ExportConfig(frame="world", overlays=False, animations=False,
                                                     top_views=False, formats=("ply",)))
    summary = json.loads((results / "summary.json").read_text())
    seq, ground = next(iter(summary["ground"].items()))
    ground = GroundFrame.from_dict(ground)
    labels = read_smpl_labels(results)
    key, labs = next(iter(labels.items()))
    mesh = trimesh.load(out / "meshes" / seq / f"{seq}_{labs[0].frame:07d}_{key[1]}.ply", process=False)
    verts = np.asarray(mesh.vertices)
    # z is the derived up: the feet are near z = 0 and the head ~1.5-2 m above them
    assert abs(verts[:, 2].min()) < 0.15
    assert 1.4 < np.ptp(verts[:, 2]) < 2.1
    back = np.linalg.inv(level_T_lidar(ground))
    lidar = verts @ back[:3, :3].T + back[:3, 3]
    assert np.allclose(ground.height(lidar), verts[:, 2], atol=1e-6)


def test_overlays_have_the_image_size_and_draw_the_fit(fitted, tmp_path):
    scene, results = fitted
    out = tmp_path / "out"
    record = export_results(results, out, scene, ExportConfig(meshes=False))
    assert record["files"]["overlays"] > 0 and record["files"]["top_views"] == 2
    for path in (out / "overlays").rglob("*.jpg"):
        cam = path.parent.name
        image = cv2.imread(str(path))
        source = cv2.imread(str(scene / "images" / path.parent.parent.name / cam / path.name))
        assert image.shape == source.shape
        assert np.abs(image.astype(int) - source.astype(int)).max() > 100     # something was drawn
    for path in (out / "topview").rglob("*.png"):
        assert cv2.imread(str(path)).shape == (720, 720, 3)
    gifs = sorted((out / "animation").rglob("*.gif"))
    assert len(gifs) == 2
    ok, animation = cv2.imreadanimation(str(gifs[0]))
    labels = read_smpl_labels(results)
    assert ok and len(animation.frames) in {len(v) for v in labels.values()}


def test_blank_canvas_has_the_calibration_size_and_reruns_are_identical(fitted, tmp_path):
    scene, results = fitted
    import shutil
    bare = tmp_path / "bare"
    shutil.copytree(scene, bare, ignore=shutil.ignore_patterns("images"))
    a, b = tmp_path / "a", tmp_path / "b"
    for out in (a, b):
        assert main(["export", str(results), "--dataset", str(bare), "--out", str(out), "--no-meshes",
                     "--every", "3"]) == 0
    assert tree_digest(a) == tree_digest(b)
    cameras = dataset_cameras(read_dataset(bare)[0].calibrations)
    for path in (a / "overlays").rglob("*.jpg"):
        width, height = cameras[path.parent.name].image_size
        assert cv2.imread(str(path)).shape == (height, width, 3)


def test_camera_jacobian_matches_finite_differences(fitted):
    scene, _ = fitted
    track = read_dataset(scene)[0]
    rng = np.random.default_rng(0)
    for camera in dataset_cameras(track.calibrations).values():
        assert isinstance(camera, Camera)
        points = track.frames[0].world_lidar_points[:3] if len(track.frames[0].world_lidar_points) else \
            camera.world_center + rng.normal(size=(3, 3)) + 20 * camera.calib.world_T_cam[:3, 2]
        jac = camera.jacobian(points, 0.5)
        eps = 1e-6
        num = np.stack([(camera.project(points + eps * e, 0.5)[0] - camera.project(points - eps * e, 0.5)[0])
                        / (2 * eps) for e in np.eye(3)], axis=-1)
        assert np.allclose(jac, num, rtol=1e-5, atol=1e-5)
