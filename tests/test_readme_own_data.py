"""The README's "Use your own data" section, followed literally: a hand-made dataset is written from what the
section says (its layout, label JSON, calibration, PLY and config blocks, its keypoint names and timestamp
format), fitted with the section's command, and every output field its tables list is in the results.  The
"Python API" block runs as printed.

The dataset: two people walking across the view of the README's example stereo pair (its calibration numbers,
a LiDAR frame with z pointing down), posed open-model bodies projected into both cameras with 1 px click noise,
their LiDAR points from the surface facing the sensor."""
from __future__ import annotations

import json
import re
import shlex
from pathlib import Path

import numpy as np
import pytest
import trimesh
from scipy.spatial.transform import Rotation

from pedx_graph.cli import main

README = Path(__file__).resolve().parents[1] / "README.md"
SEQUENCE, LEFT, RIGHT = "20240501T0930", "camL", "camR"
FRAMES = range(6)
FPS = 10.0
GROUND_BELOW_LIDAR_M = 1.7          # the README's YAML example: ground_offset_m -1.7 with world_up (0, 0, -1)


def section(title: str) -> str:
    text = README.read_text()
    start = text.index(f"## {title}\n")
    end = text.find("\n## ", start + 1)
    return text[start:end if end > 0 else None]


def code_blocks(text: str) -> list[tuple[str, str]]:
    return re.findall(r"```(\w*)\n(.*?)```", text, flags=re.S)


def block(text: str, lang: str, contains: str = "") -> str:
    found = [body for kind, body in code_blocks(text) if kind == lang and contains in body]
    assert found, f"README: no {lang} block containing {contains!r}"
    return found[0]


def key_values(text: str) -> dict[str, np.ndarray]:
    """``key: numbers`` lines (the README's calibration blocks)."""
    out = {}
    for line in text.strip().splitlines():
        key, values = line.split(":", 1)
        out[key.strip()] = np.array([float(v) for v in values.split()])
    return out


def table_fields(text: str, after: str) -> list[str]:
    """Field names (backquoted, first column) of the first markdown table after ``after``."""
    rest = text[text.index(after):]
    rows = re.search(r"\| field \| meaning \|\n\|---\|---\|\n((?:\|.*\|\n)+)", rest).group(1)
    names = []
    for row in rows.splitlines():
        names += re.findall(r"`([^`]+)`", row.split("|")[1])
    return names


class Readme:
    """What the "Use your own data" section says, parsed from its text."""

    def __init__(self):
        own = section("Use your own data")
        self.text = own
        layout = block(own, "text", "calib_cam_to_cam_")
        self.paths = {}
        for line in layout.strip().splitlines():
            path = line.split()[0].removeprefix("MYDATA/")
            kind = ("cam_to_cam" if "cam_to_cam" in path else "cam_to_range" if "cam_to_range" in path else
                    "label2d" if path.startswith("labels/2d/") else "segment" if "segment" in path else
                    "timestamps" if path.startswith("timestamps/") else path.split("/")[0])
            self.paths[kind] = path
        self.label = json.loads(block(own, "json"))
        self.cam_to_cam = key_values(block(own, "text", "P_rect_01:"))
        self.cam_to_range = key_values(block(own, "text", "T:"))
        self.ply_header = block(own, "text", "end_header").split("end_header")[0] + "end_header\n"
        self.yaml = block(own, "yaml")
        names = own[own.index("The keypoint names:"):].split("(")[0]
        self.keypoint_names = re.findall(r"`([a-z]+)`", names)
        commands = block(own, "bash", "pedx-graph fit MYDATA")
        self.fit_command = next(line.split("#")[0].strip() for line in commands.splitlines()
                                if line.startswith("pedx-graph fit "))
        self.frame_fields = table_fields(own, "**What comes out.**")
        self.track_fields = table_fields(own, "`MYRESULTS/summary.json`")
        summary_text = own[own.index("`MYRESULTS/summary.json`"):].split("| field")[0]
        self.summary_fields = [f for f in re.findall(r"`([a-z_]+)`", summary_text)]

    def path(self, kind: str, **names) -> str:
        out = self.paths[kind]
        for key, value in names.items():
            out = out.replace(f"<{key}>", value)
        assert "<" not in out, out
        return out


def walker_pose(phase: float) -> np.ndarray:
    """(72,) a walking body pose: arms down, legs swinging with ``phase`` (radians)."""
    body = np.zeros((24, 3))
    body[16] = [0.0, 0.0, -1.2]          # left shoulder: the arm from sideways to down
    body[17] = [0.0, 0.0, 1.2]
    body[1, 0], body[2, 0] = 0.35 * np.sin(phase), -0.35 * np.sin(phase)     # hips about their x axes
    body[4, 0], body[5, 0] = 0.3 * max(np.sin(phase), 0), 0.3 * max(-np.sin(phase), 0)   # knees
    return body.ravel()


def people(model) -> dict[str, list[dict]]:
    """Two walkers in the README's z-down LiDAR frame: tracking id -> per frame the posed body."""
    world_up = np.array([0.0, 0.0, -1.0])
    out = {}
    for tid, start, velocity, body_x in (("walker1", [9.0, -1.0], [0.0, 1.3], [1.0, 0.0, 0.0]),
                                         ("walker2", [12.0, 1.5], [0.0, -1.2], [-1.0, 0.0, 0.0])):
        forward = np.array([velocity[0], velocity[1], 0.0]) / np.linalg.norm(velocity)
        world_R_body = np.column_stack([body_x, world_up, forward])      # body frame: y up, z forward
        assert np.isclose(np.linalg.det(world_R_body), 1.0)
        frames = []
        for k in FRAMES:
            pose = walker_pose(2.0 * k / FPS * 2 * np.pi)
            pose[:3] = Rotation.from_matrix(world_R_body).as_rotvec()
            betas = np.zeros(model.num_betas)
            at_zero = model.forward(pose, betas, np.zeros(3))
            centre = np.array(start + [0.0]) + np.array(velocity + [0.0]) * k / FPS
            trans = centre - at_zero.joints[0]
            trans[2] += GROUND_BELOW_LIDAR_M - (at_zero.vertices[:, 2] + trans[2]).max()   # feet on the ground
            frames.append({"pose": pose, "betas": betas, "trans": trans,
                           "posed": model.forward(pose, betas, trans)})
        out[tid] = frames
    return out


def project(readme: Readme, world_p: np.ndarray, side: str) -> np.ndarray:
    """Pixels of world (LiDAR) points in the README pair's rectified left / right image, as the README says:
    ``lidar_p = R @ camera_p + T``, both ``P_rect`` applied to the rectified left camera's points."""
    lidar_R_cam = readme.cam_to_range["R"].reshape(3, 3)
    cam_p = (world_p - readme.cam_to_range["T"]) @ lidar_R_cam
    rect_p = cam_p @ readme.cam_to_cam["R_rect_00"].reshape(3, 3).T
    P = readme.cam_to_cam["P_rect_00" if side == "left" else "P_rect_01"].reshape(3, 4)
    hom = rect_p @ P[:, :3].T + P[:, 3]
    return hom[:, :2] / hom[:, 2:3]


def write_dataset(root: Path, readme: Readme, walkers: dict, model) -> None:
    rng = np.random.default_rng(0)
    files = {readme.path("cam_to_cam", left=LEFT, right=RIGHT): readme.cam_to_cam,
             readme.path("cam_to_range", left=LEFT): readme.cam_to_range}
    for rel, keys in files.items():
        (root / rel).parent.mkdir(parents=True, exist_ok=True)
        (root / rel).write_text("".join(f"{k}: {' '.join(f'{v:g}' for v in values)}\n" for k, values in keys.items()))
    width, height = readme.cam_to_cam["S_rect_00"]
    names = list(model.keypoint_names)
    mesh_normals = {}
    for tid, frames in walkers.items():
        for k, body in zip(FRAMES, frames):
            frame = f"{k:07d}"
            for cam, side in ((LEFT, "left"), (RIGHT, "right")):
                uv = project(readme, body["posed"].keypoints, side) + rng.normal(0.0, 1.0, (len(names), 2))
                outline = project(readme, body["posed"].vertices, side)
                assert np.all((uv > 0) & (uv < [width, height])), "a keypoint left the image: move the walkers"
                lo, hi = outline.min(axis=0), outline.max(axis=0)
                label = dict(readme.label, tracking_id=tid, frame_id=k,
                             polygon=[[lo[0], lo[1]], [hi[0], lo[1]], [hi[0], hi[1]], [lo[0], hi[1]]],
                             keypoint={name: {"x": float(uv[names.index(name)][0]),
                                              "y": float(uv[names.index(name)][1]), "visible": True}
                                       for name in readme.keypoint_names})
                path = root / readme.path("label2d", seq=SEQUENCE, cam=cam, frame=frame, tid=tid)
                path.parent.mkdir(parents=True, exist_ok=True)
                path.write_text(json.dumps(label, indent=1))
            # LiDAR points: the surface facing the sensor (at the origin), 1 cm noise
            mesh = trimesh.Trimesh(body["posed"].vertices, model.faces, process=False)
            mesh_normals[tid] = mesh.vertex_normals
            towards = -mesh.vertices / np.linalg.norm(mesh.vertices, axis=1, keepdims=True)
            facing = np.flatnonzero(np.einsum("ij,ij->i", mesh.vertex_normals, towards) > 0.3)
            chosen = rng.choice(facing, size=min(150, len(facing)), replace=False)
            points = mesh.vertices[chosen] + rng.normal(0.0, 0.01, (len(chosen), 3))
            header = re.sub(r"element vertex \d+", f"element vertex {len(points)}", readme.ply_header)
            path = root / readme.path("segment", seq=SEQUENCE, frame=frame, tid=tid)
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_text(header + "".join(f"{p[0]:.4f} {p[1]:.4f} {p[2]:.4f}\n" for p in points))
    stamps = root / readme.path("timestamps", seq=SEQUENCE)
    stamps.parent.mkdir(parents=True, exist_ok=True)
    stamps.write_text("".join(f"{k} {k / FPS}\n" for k in FRAMES))     # "one `frame seconds` line per frame"


@pytest.fixture(scope="module")
def readme() -> Readme:
    return Readme()


@pytest.fixture(scope="module")
def own_dataset(tmp_path_factory, readme):
    from pedx_graph import BodyModel

    model = BodyModel.load()
    walkers = people(model)
    root = tmp_path_factory.mktemp("own") / "MYDATA"
    write_dataset(root, readme, walkers, model)
    return root, walkers


def run_fit(readme: Readme, root: Path, out: Path, *extra: str) -> dict:
    argv = shlex.split(readme.fit_command.replace("MYDATA", str(root)).replace("MYRESULTS", str(out)))
    assert argv[0] == "pedx-graph"
    assert main(argv[1:] + ["--quiet", *extra]) == 0
    return json.loads((out / "summary.json").read_text())


def test_the_section_states_what_the_code_reads(readme):
    from pedx_graph.keypoints import PEDX_KEYPOINTS

    assert tuple(readme.keypoint_names) == PEDX_KEYPOINTS
    assert readme.label["category"] == "pedestrian"
    assert set(readme.label) == {"tracking_id", "category", "subtype", "frame_id", "polygon", "keypoint"}
    assert {"cam_to_cam", "cam_to_range", "label2d", "segment", "timestamps", "pointclouds"} <= set(readme.paths)
    assert "<!-- detector-input -->" in readme.text or "pedx-graph import" in readme.text


def test_own_dataset_fits_as_the_readme_says(own_dataset, readme, tmp_path):
    root, walkers = own_dataset
    summary = run_fit(readme, root, tmp_path / "MYRESULTS")
    assert summary["status"] == "complete"
    assert summary["counts"]["done"] == 2 and summary["counts"]["failed"] == 0
    # the up axis derived from the data: the README's z-down LiDAR frame
    ground = summary["ground"][SEQUENCE]
    assert np.dot(ground["world_up"], [0.0, 0.0, -1.0]) > np.cos(np.radians(3.0))
    for field in readme.summary_fields:
        assert field in summary, f"README names summary.json field {field!r}"
    for record in summary["tracks"]:
        for field in readme.track_fields:
            assert field in record, f"README names track field {field!r}"
    from pedx_graph import read_smpl_labels

    results = read_smpl_labels(tmp_path / "MYRESULTS")
    errors = []
    for (sequence, tid), labels in results.items():
        assert sequence == SEQUENCE and len(labels) == len(FRAMES)
        for label in labels:
            for field in readme.frame_fields:
                assert field in ("betas", "pose", "trans") or field in label.extra, \
                    f"README names result field {field!r}"
            truth = walkers[tid][label.frame]["posed"].keypoints
            errors.append(np.linalg.norm(np.asarray(label.extra["keypoints_3d"]) - truth, axis=1).mean())
    assert np.mean(errors) < 0.017                     # metres; measured 11 mm (8-14 mm per frame)


def test_ground_override_from_the_readme_yaml(own_dataset, readme, tmp_path):
    root, _ = own_dataset
    config = tmp_path / "my_fit.yaml"
    config.write_text(readme.yaml)
    summary = run_fit(readme, root, tmp_path / "MYRESULTS", "--config", str(config))
    ground = summary["ground"][SEQUENCE]
    assert ground["world_up"] == pytest.approx([0.0, 0.0, -1.0], abs=1e-9)
    assert ground["ground_offset_m"] == pytest.approx(-GROUND_BELOW_LIDAR_M)
    assert summary["counts"]["done"] == 2


def test_python_api_block_runs_as_printed(own_dataset):
    root, _ = own_dataset
    code = block(section("Python API"), "python", "read_dataset")
    assert len(code.strip().splitlines()) == 4
    namespace: dict = {}
    exec(code.replace('"SIM"', repr(str(root))), namespace)       # noqa: S102 - the README's own lines
    result = namespace["result"]
    cov = np.asarray(result.extra_per_frame[0]["cov_keypoints_3d"])
    assert cov.shape == (18, 3, 3) and np.all(np.linalg.eigvalsh(cov) > 0)
    assert result.world_keypoints.shape == (len(FRAMES), 18, 3)
