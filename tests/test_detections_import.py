"""`pedx-graph import openpose`: own OpenPose files made on distorted images of a simulated scene -> a dataset the
reader and the fit take, with the set's keypoints rectified back to the true pixels."""
import dataclasses
import json

import numpy as np

from pedx_graph.body import BodyModel
from pedx_graph.cli import main
from pedx_graph.config import load_config, to_dict
from pedx_graph.data.calib import read_calibrations, write_stereo_calibration
from pedx_graph.data.reader import read_dataset, read_smpl_labels
from pedx_graph.data.types import RawCamera
from pedx_graph.detections.importer import ImportConfig, import_detections
from pedx_graph.detections.noise import DetectionNoiseConfig, detection_height_px, stereo_row_scale
from pedx_graph.detections.openpose import read_openpose
from pedx_graph.detections.undistort import distort
from scene_fixtures import small_scene


def distorted_rig(root):
    """The scene's pairs, each camera given a distorted raw image model (written into the calibration files)."""
    raw_calibs = {}
    for name, calib in read_calibrations(root / "calib").items():
        raws = [RawCamera(raw_K=P[:, :3].copy(), raw_D=np.array([-0.2, 0.08, 0.001, -0.001, 0.0]),
                          rect_R_cam=calib.rect_R_cam, P_rect=P) for P in (calib.left_P_rect, calib.right_P_rect)]
        raw_calibs[name] = dataclasses.replace(calib, left_raw=raws[0], right_raw=raws[1])
        write_stereo_calibration(root / "calib", raw_calibs[name])
    return raw_calibs


def write_openpose_truth(root, raw_calibs, files, noise_px=None) -> dict:
    """OpenPose BODY_25 files (confidence 0.9, ``person_id`` = the person's number) of every labelled person of
    the scene, on the raw images; ``noise_px(calib, side, rect_uv) -> (25,) sigma`` adds Gaussian noise to the
    rectified pixels before distortion (None: exact).  Returns ``(camera, frame, number) -> rectified pixels``
    (noise-free) of every detection written."""
    model = BodyModel.load().for_keypoint_set("body25")
    rng = np.random.default_rng(0)
    expected = {}
    for number, ((seq, tid), labels) in enumerate(sorted(read_smpl_labels(root).items())):
        for lab in labels:
            world = model.keypoints(lab.pose, lab.betas, lab.trans)
            for name, calib in raw_calibs.items():
                for side, cam in zip(("left", "right"), name.split("-")):
                    rect = calib.project(world)[0 if side == "left" else 1]
                    noisy = rect if noise_px is None else \
                        rect + rng.normal(size=rect.shape) * noise_px(calib, side, rect)[:, None]
                    raw_uv = distort(noisy, calib.left_raw if side == "left" else calib.right_raw)
                    w, h = calib.image_size
                    if not np.all((raw_uv > 0) & (raw_uv < [w, h])):
                        continue
                    path = files / f"{seq}_{cam}_{lab.frame:07d}_keypoints.json"
                    doc = json.loads(path.read_text()) if path.is_file() else {"version": 1.3, "people": []}
                    flat = np.c_[raw_uv, np.full(25, 0.9)].ravel().tolist()
                    doc["people"].append({"person_id": [number], "pose_keypoints_2d": flat})
                    path.parent.mkdir(parents=True, exist_ok=True)
                    path.write_text(json.dumps(doc))
                    expected[(cam, lab.frame, str(number))] = rect
    return expected


def nearest_person_error(result, truth: dict, model) -> float:
    """Mean keypoint error (m) of a fitted track against the true pedestrian it lies on: the smallest over the
    people (``read_smpl_labels``) labelled on at least half of its frames."""
    errors = []
    for labels in truth.values():
        by_frame = {lab.frame: lab for lab in labels}
        common = [i for i, f in enumerate(result.frames) if f in by_frame]
        if len(common) >= len(result.frames) // 2:
            errors.append(np.mean([np.linalg.norm(result.world_keypoints[i] - model.keypoints(
                by_frame[result.frames[i]].pose, by_frame[result.frames[i]].betas,
                by_frame[result.frames[i]].trans), axis=1).mean() for i in common]))
    return min(errors)


def test_import_openpose_with_file_ids(tmp_path):
    root = small_scene(tmp_path / "scene", pedestrians=2, frames=4, seed=1)
    raw_calibs = distorted_rig(root)
    truth = read_smpl_labels(root)
    files = tmp_path / "openpose"
    expected = write_openpose_truth(root, raw_calibs, files)
    assert expected
    out = tmp_path / "imported"
    assert main(["import", "openpose", str(files), "--calib", str(root), "--out", str(out), "--use-file-ids"]) == 0
    summary = json.loads((out / "import_summary.json").read_text())
    assert summary["keypoint_sets"] == ["body25"] and (out / "pointclouds").exists()
    for record in summary["sequences"].values():            # the identity review rides along (review.py)
        review = record["identity_review"]
        assert 0 <= review["flagged_track_frames"] <= review["track_frames"] and review["track_frames"] > 0
        assert all(len(s["tracks"]) == 2 and s["first_frame"] <= s["last_frame"] for s in review["stretches"])
    saved = load_config(ImportConfig, out / "import_config.yaml")          # the resolved config beside the output
    assert saved.use_file_ids and to_dict(saved) == to_dict(dataclasses.replace(ImportConfig(), use_file_ids=True))
    tracks = read_dataset(out)
    assert {t.tracking_id for t in tracks} <= {str(i) for i in range(len(truth))} and tracks
    checked = 0
    cam_of = {(name, side): cam for name in raw_calibs for side, cam in zip(("left", "right"), name.split("-"))}
    for track in tracks:
        assert track.keypoint_set == "body25"
        for fr in track.frames:
            for pair, side, view in fr.labelled_views():
                want = expected[(cam_of[(pair, side)], fr.frame, track.tracking_id)]
                assert np.abs(view.keypoints - want).max() < 1e-3          # undistorted + rectified
                assert view.sigma_px is not None and np.all(view.sigma_px > 0)
                checked += 1
    assert checked >= len(expected) // 2
    # the LiDAR cut needs no association: with file ids the centres are triangulated, the points cut
    assert sum(v["segments"]["segments"] for v in summary["sequences"].values()) > 0
    true_trans = {(str(n), lab.frame): np.asarray(lab.trans, dtype=float)
                  for n, (_, labels) in enumerate(sorted(truth.items())) for lab in labels}
    cut = [(track.tracking_id, fr) for track in tracks for fr in track.frames if len(fr.world_lidar_points)]
    assert cut
    for tid, fr in cut:
        offset = np.median(fr.world_lidar_points, axis=0) - true_trans[(tid, fr.frame)]
        assert np.linalg.norm(offset[:2]) < 0.5, (tid, fr.frame, offset)


def test_the_association_lidar_cut_defines_the_written_segments(tmp_path, capsys):
    """One definition of the cut: ``association.lidar_cut`` also cuts the segments written for the fit, and
    the old top-level ``lidar_cut`` of the import config is refused, naming the key."""
    root = small_scene(tmp_path / "scene", pedestrians=2, frames=3, seed=1)
    files = tmp_path / "openpose"
    assert write_openpose_truth(root, distorted_rig(root), files)
    args = ["import", "openpose", str(files), "--calib", str(root), "--use-file-ids"]
    segments = {}
    for name, clearance in (("default", None), ("high", 3.0)):
        config = tmp_path / f"{name}.yaml"
        config.write_text("" if clearance is None else
                          f"association:\n  lidar_cut:\n    ground_clearance_m: {clearance}\n")
        out = tmp_path / name
        assert main(args + ["--out", str(out), "--config", str(config)]) == 0
        segments[name] = sum(len(fr.world_lidar_points) for track in read_dataset(out) for fr in track.frames)
    # nobody's points lie 3 m above the ground: the segments follow the association's cut options
    assert segments["default"] > 0 and segments["high"] == 0
    old = tmp_path / "old.yaml"
    old.write_text("lidar_cut:\n  ground_clearance_m: 3.0\n")
    capsys.readouterr()
    assert main(args + ["--out", str(tmp_path / "old"), "--config", str(old)]) != 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "lidar_cut" in err[0] and str(old) in err[0]


def test_import_simulated_detector_output_then_fit(tmp_path):
    """The simulator's own detector files (no ids, distorted images, clutter): import COCO results and OpenPose
    BODY_25B through the association, then fit; each fitted track lies on one true pedestrian."""
    from pedx_graph.sim.config import SimConfig
    from pedx_graph.solvers.fit import fit_track

    config = SimConfig()
    config.detections.formats = ("coco", "openpose_body25b")
    root = small_scene(tmp_path / "scene", pedestrians=3, frames=10, seed=0, config=config)
    seq = next((root / "detections" / "coco").iterdir())
    truth = read_smpl_labels(root)
    model = BodyModel.load()
    runs = {"coco17": ["coco", str(seq / "keypoint_results.json"), "--images", str(seq / "image_list.json")],
            "body25b": ["openpose", str(root / "detections" / "openpose_body25b"), "--keypoint-set", "body25b"]}
    for set_name, args in runs.items():
        out = tmp_path / set_name
        assert main(["import", *args, "--calib", str(root), "--out", str(out)]) == 0
        tracks = [t for t in read_dataset(out) if len(t.frames) >= 4]
        assert tracks and all(t.keypoint_set == set_name for t in tracks)
        track_errors = []
        for track in tracks[:2]:
            result = fit_track(track)
            track_errors.append(nearest_person_error(result, truth, model))
        # Seed 0 measured: coco17 0.11 m (one track), body25b 0.17 and 0.30 m (manual labels of the same people:
        # 0.04 and 0.08 m; the detector's noise, misses and one-image frames cost the rest).  A broken reader,
        # undistortion or keypoint definition, or a track mixing two people, is off by far more.
        assert max(track_errors) < 0.45 and np.mean(track_errors) < 0.35, (set_name, track_errors)


def test_import_and_fit_detections_on_the_real_pedx_rig(tmp_path):
    """The detector path on the real rig's conventions (the simulator's ``pedx`` preset: z-down LiDAR frame,
    ground tilted ~1 degree and 0.3 m below the origin, the real pairs): OpenPose BODY_25 files without ids
    imported with the scene clouds, then fitted.  Nothing tells the import or the fit the frame: the ground it
    derives is the true one, every fitted body stands upright on it (head ~1.5 m above the ankles along the
    derived up axis: an assumed z-up frame turns bodies inside out) with plausible shape coefficients, and
    each track lies on one true pedestrian."""
    from pedx_graph.keypoints import PEDX_KEYPOINTS
    from pedx_graph.sim.config import PEDX_GROUND_BELOW_ORIGIN_M, pedx_rig_config
    from pedx_graph.solvers.fit import fit_track

    config = pedx_rig_config()
    config.detections.formats = ("openpose_body25",)
    root = small_scene(tmp_path / "scene", pedestrians=4, frames=10, seed=0, config=config)
    out = tmp_path / "imported"
    assert main(["import", "openpose", str(root / "detections" / "openpose_body25"), "--keypoint-set", "body25",
                 "--calib", str(root), "--out", str(out)]) == 0
    tracks = [t for t in read_dataset(out) if len(t.frames) >= 4]
    assert len(tracks) >= 2
    true_up = np.asarray(config.output_frame.output_up, dtype=float)
    ground = tracks[0].ground
    assert np.degrees(np.arccos(np.clip(ground.world_up @ true_up, -1, 1))) < 0.5
    assert abs(ground.ground_offset_m + PEDX_GROUND_BELOW_ORIGIN_M) < 0.05
    model = BodyModel.load()
    head, ankles = PEDX_KEYPOINTS.index("head"), [PEDX_KEYPOINTS.index(k) for k in ("lankl", "rankl")]
    truth = read_smpl_labels(root)
    track_errors = []
    for track in tracks[:2]:
        result = fit_track(track)
        assert np.max(np.abs(result.betas)) < 3.0
        for i in range(len(result.frames)):
            kps = model.keypoints(result.pose[i], result.betas, result.trans[i])
            assert (kps[head] - kps[ankles].mean(axis=0)) @ ground.world_up > 1.2
        track_errors.append(nearest_person_error(result, truth, model))
    # Seed 0 measured: 0.023 and 0.027 m (the two tracks of ten frames); a body placed on the wrong side of the
    # rig, mirrored, upside down or between two people is off by far more.
    assert max(track_errors) < 0.04, track_errors


def test_stereo_row_scale_bounds_the_noise_from_below():
    """Row differences of known spread: the scale comes back, each pair's offset is removed; a scale below 1
    is reported but never applied (the rows only bound the noise from below); too few samples: no check."""
    rng = np.random.default_rng(2)
    sd = rng.uniform(2.0, 9.0, 4000)
    rows = {"a-b": (1.3 + 2.0 * sd[:2000] * rng.normal(size=2000), sd[:2000]),
            "c-d": (-0.8 + 2.0 * sd[2000:] * rng.normal(size=2000), sd[2000:])}
    check = stereo_row_scale(rows)
    assert check.samples == 4000 and abs(check.scale - 2.0) < 0.1 and check.applied == check.scale
    assert abs(check.pair_offsets_px["a-b"] - 1.3) < 0.3 and abs(check.pair_offsets_px["c-d"] + 0.8) < 0.3
    calm = stereo_row_scale({"a-b": (0.5 * sd * rng.normal(size=4000), sd)})
    assert abs(calm.scale - 0.5) < 0.05 and calm.applied == 1.0
    few = stereo_row_scale({"a-b": (rows["a-b"][0][:50], rows["a-b"][1][:50])}, min_samples=200)
    assert few.scale is None and few.applied == 1.0 and few.samples == 50
    # per confidence: a curve whose low-confidence end is three times too confident shows there
    confidence = np.where(np.arange(4000) % 2 == 0, 0.31, 0.79)
    shaped = np.where(confidence < 0.5, 3.0, 1.0) * sd * rng.normal(size=4000)
    check = stereo_row_scale({"a-b": (shaped, sd, confidence)}, knots=(0.1, 0.3, 0.5, 0.8))
    (low, high) = check.by_confidence
    assert (low["knot"], high["knot"]) == (0.3, 0.8) and low["count"] == high["count"] == 2000
    assert abs(low["scale"] - 3.0) < 0.2 and abs(high["scale"] - 1.0) < 0.07


def _noisier_than_the_model(tmp_path, factor: float):
    """A small scene on a distorted rig and its people's OpenPose files with ``factor`` times the noise model's
    noise (independent in the two images): ``(scene root, raw calibrations, files folder)``."""
    root = small_scene(tmp_path / "scene", pedestrians=3, frames=6, seed=4)
    raw_calibs = distorted_rig(root)
    noise = DetectionNoiseConfig()

    def scaled_model(calib, side, rect_uv):
        return factor * noise.sigma("body25", np.full(25, 0.9), height_px=detection_height_px(rect_uv))

    files = tmp_path / "noisy"
    write_openpose_truth(root, raw_calibs, files, noise_px=scaled_model)
    return root, raw_calibs, files


def test_a_detector_noisier_than_the_model_raises_every_sigma(tmp_path, capsys):
    """Detections three times as noisy as the noise model says (independent in the two images): the import's
    stereo-row check finds about 3 and multiplies every written sigma by it; exact detections change
    nothing."""
    root, raw_calibs, files = _noisier_than_the_model(tmp_path, 3.0)
    sigmas = {}
    for check in (True, False):
        out = tmp_path / f"imported_{check}"
        config = ImportConfig(use_file_ids=True, stereo_noise_check=check)
        summary = import_detections(read_openpose(files), root, out, config=config)
        (record,) = summary["sequences"].values()
        sigmas[check] = {(t.tracking_id, fr.frame, pair, side): view.sigma_px for t in read_dataset(out)
                         for fr in t.frames for pair, side, view in fr.labelled_views()}
        if check:
            found = record["stereo_noise_check"]
            assert found["samples"] >= 200 and 2.6 < found["scale"] < 3.4 and found["applied"] == found["scale"]
        else:
            assert record["stereo_noise_check"] is None
    assert sigmas[True].keys() == sigmas[False].keys() and sigmas[True]
    for key, sigma in sigmas[True].items():
        np.testing.assert_allclose(sigma, found["applied"] * sigmas[False][key], rtol=1e-3)
    # the command line says so
    assert main(["import", "openpose", str(files), "--calib", str(root), "--out", str(tmp_path / "cli"),
                 "--use-file-ids"]) == 0
    printed = capsys.readouterr().out
    assert f"stereo rows show {found['scale']:.2f}x the noise model's keypoint noise" in printed
    assert f"sigmas x{found['applied']:.2f}" in printed
    exact = tmp_path / "exact"
    write_openpose_truth(root, raw_calibs, exact)
    summary = import_detections(read_openpose(exact), root, tmp_path / "imported_exact",
                                config=ImportConfig(use_file_ids=True))
    (record,) = summary["sequences"].values()
    assert record["stereo_noise_check"]["applied"] == 1.0


def test_the_definitions_uncertainty_is_added_at_the_persons_scale_after_the_stereo_check(tmp_path):
    """``noise.definition_sigma_m``: every written sigma gains that many metres at the person's pixels per metre
    (its keypoints' image span over the set's standing span), in quadrature; the stereo-row check, which such
    an offset cannot show (it is the same in both images), judges the detector's noise alone."""
    from pedx_graph.detections.noise import standing_span_m

    root, _, files = _noisier_than_the_model(tmp_path, 2.0)
    views, checks = {}, {}
    for definition in (0.0, 0.03):
        config = ImportConfig(use_file_ids=True)
        config.noise.definition_sigma_m = definition
        summary = import_detections(read_openpose(files), root, tmp_path / f"d{definition}", config=config)
        (record,) = summary["sequences"].values()
        checks[definition] = record["stereo_noise_check"]["applied"]
        views[definition] = {(t.tracking_id, fr.frame, pair, side): view
                             for t in read_dataset(tmp_path / f"d{definition}")
                             for fr in t.frames for pair, side, view in fr.labelled_views()}
    assert checks[0.0] == checks[0.03] and 1.6 < checks[0.0] < 2.4
    assert views[0.0].keys() == views[0.03].keys() and len(views[0.0]) > 20
    assert 1.2 < standing_span_m("body25") < 1.8            # nose-or-head to toes of a standing person
    for key, view in views[0.03].items():
        added = 0.03 * detection_height_px(view.keypoints) / standing_span_m("body25")
        np.testing.assert_allclose(view.sigma_px, np.hypot(views[0.0][key].sigma_px, added), rtol=1e-6)
        assert added > 1.0                                   # a 3 cm offset is pixels at these people's size


def test_import_with_two_workers_writes_what_one_process_writes(tmp_path):
    """``--workers 2`` runs the two stereo pairs' association steps in two processes: every file the import
    writes (labels, LiDAR segments, summary, resolved config) is byte for byte what one process writes."""
    from pedx_graph.sim.config import pedx_rig_config

    config = pedx_rig_config()                  # its two pairs see the same street: both hold people
    config.detections.formats = ("openpose_body25",)
    root = small_scene(tmp_path / "scene", pedestrians=4, frames=10, seed=0, config=config)
    written = {}
    for workers in (1, 2):
        out = tmp_path / f"workers{workers}"
        assert main(["import", "openpose", str(root / "detections" / "openpose_body25"), "--keypoint-set", "body25",
                     "--calib", str(root), "--out", str(out), "--workers", str(workers)]) == 0
        written[workers] = {path.relative_to(out).as_posix(): path.read_bytes()
                            for path in sorted(out.rglob("*")) if path.is_file() and not path.is_symlink()
                            and "pointclouds" not in path.relative_to(out).parts}
    labels = [name for name in written[1] if name.startswith("labels/2d/")]
    cameras = {name.split("/")[3] for name in labels}
    # both pairs' cameras hold labels: the two processes each had a pair to associate
    assert len(cameras) == 4, cameras
    assert written[2] == written[1]


def test_scene_clouds_are_read_once_within_the_cache_and_pickle_without_it(tmp_path, monkeypatch):
    """The import's scene clouds: frames visited track after track are read from disk once while they fit in
    ``cloud_cache_mb``; with no room, one frame at a time; a pickled reader (for worker processes) carries no
    points."""
    import pickle

    import pedx_graph.data.ply as ply
    from pedx_graph.detections.importer import _Clouds

    rng = np.random.default_rng(3)
    clouds = {frame: rng.normal(size=(1000, 3)) for frame in range(4)}      # 24 kB each
    for frame, points in clouds.items():
        path = ply.pointcloud_path(tmp_path, "seq", frame)
        path.parent.mkdir(parents=True, exist_ok=True)
        ply.write_ply_points(path, points)
    reads = []
    original = ply.read_ply_points
    monkeypatch.setattr(ply, "read_ply_points", lambda path, *a, **k: reads.append(path) or original(path, *a, **k))
    visits = [0, 1, 2, 3] * 3                          # three tracks over the same frames
    for cache_mb, expected in ((1.0, 4), (0.0, 12)):
        reads.clear()
        reader = _Clouds(tmp_path, "seq", cache_mb)
        for frame in visits:
            np.testing.assert_array_equal(reader[frame], clouds[frame])
        assert len(reads) == expected, (cache_mb, len(reads))
    assert sorted(reader) == [0, 1, 2, 3]
    restored = pickle.loads(pickle.dumps(_Clouds(tmp_path, "seq", 1.0)))
    full = _Clouds(tmp_path, "seq", 1.0)
    for frame in range(4):
        full[frame]
    assert len(pickle.dumps(full)) < 20_000 and len(restored) == 4
