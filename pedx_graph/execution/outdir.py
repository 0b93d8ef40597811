"""The results folder of a run (``--out``): refusals, the run manifest, per-track completion markers,
timings and the summary.

Layout written by ``fit``, ``stream`` and ``baseline``::

    OUT/manifest.json                 what the run is: command, method, dataset, config hash, version
    OUT/<command>_config.yaml         the resolved config(s)
    OUT/labels/3d/smpl/<seq>/...      per-frame results (PedX SMPL layout; no timings: byte-stable)
    OUT/causal/labels/3d/smpl/...     (stream) the causal estimates
    OUT/done/<seq>/<tid>.json         completion marker of a track, written after all of its files:
                                      its files and its summary records
    OUT/timings.jsonl                 one line per completed track: its timings (appended)
    OUT/summary.json                  always written (also after a failure or an interrupt)

Refusals (:class:`RunFolderError`, one line naming the path): an ``--out`` equal to or inside the dataset;
an existing non-empty ``--out`` unless ``resume`` (its manifest must match this run) or ``overwrite``
(refused too when the folder looks like a dataset; only the entries above are removed).
"""
from __future__ import annotations

import hashlib
import json
import logging
import shutil
from collections.abc import Iterable
from pathlib import Path
from urllib.parse import quote

from pedx_graph import __version__
from pedx_graph.execution.tasks import TaskOutcome, json_bytes
from pedx_graph.utils import atomic_write_bytes, atomic_writer, to_jsonable

log = logging.getLogger(__name__)

MANIFEST = "manifest.json"
DONE = "done"
TIMINGS = "timings.jsonl"
SUMMARY = "summary.json"
MANIFEST_FORMAT = "pedx-graph run 1"
#: Entries of a results folder that a run writes (and ``overwrite`` removes); eval.* are reports of the
#: results being replaced.
OWNED = (MANIFEST, DONE, TIMINGS, SUMMARY, "causal", "fit_config.yaml", "stream_config.yaml",
         "baseline_config.yaml", "eval.json", "eval.md")


class RunFolderError(ValueError):
    """A results folder that cannot be used for this run (the message names it and says why)."""


def config_sha256(configs: dict) -> str:
    """SHA-256 of the configs (name -> dataclass or plain data) as canonical JSON."""
    import dataclasses

    plain = {name: to_jsonable(dataclasses.asdict(cfg) if dataclasses.is_dataclass(cfg) else cfg)
             for name, cfg in sorted(configs.items())}
    return hashlib.sha256(json.dumps(plain, sort_keys=True).encode("utf-8")).hexdigest()


def build_manifest(command: str, method: str, dataset, sequences, configs: dict) -> dict:
    """The run manifest: the same for every run of the same work (no times, no executor)."""
    from pedx_graph.data.reader import resolve_root

    return {"format": MANIFEST_FORMAT, "command": command, "method": method,
            "dataset": str(resolve_root(dataset).resolve()),
            "sequences": None if sequences is None else sorted(set(sequences)),
            "config_sha256": config_sha256(configs), "package_version": __version__}


def _within(child: Path, parent: Path) -> bool:
    return child == parent or parent in child.parents


def looks_like_dataset(path: Path) -> bool:
    """A folder holding a dataset's inputs (``calib/`` or ``labels/2d``, itself or in ``data/``)."""
    return any((base / "calib").is_dir() or (base / "labels" / "2d").is_dir() for base in (path, path / "data"))


def marker_name(key: tuple[str, str]) -> Path:
    """``<seq>/<tid>.json`` with characters outside ``[A-Za-z0-9_.~-]`` escaped."""
    seq, tid = key
    return Path(quote(seq, safe="")) / f"{quote(tid, safe='')}.json"


class RunFolder:
    """One run's results folder (see the module docstring)."""

    def __init__(self, path, manifest: dict, fresh: bool = True, overwrite: bool = False):
        self.path = Path(path)
        self.manifest = manifest
        self.fresh = fresh
        """No previous run to continue: the manifest is (re)written."""
        self.overwrite = overwrite
        """A previous run's entries are removed first."""

    # --- before anything is written --------------------------------------------------------------------
    @classmethod
    def check(cls, out, dataset, manifest: dict, resume: bool = False, overwrite: bool = False) -> "RunFolder":
        """Refuse an unusable ``out`` (nothing is written here); the folder is made by :meth:`prepare`."""
        from pedx_graph.data.reader import resolve_root

        if resume and overwrite:
            raise RunFolderError("resume and overwrite exclude each other")
        out = Path(out)
        target = out.resolve()
        for root in {Path(dataset).resolve(), resolve_root(dataset).resolve()}:
            if _within(target, root):
                raise RunFolderError(f"{out}: the results folder is the dataset or inside it ({root}); its "
                                     "labels would mix with (or overwrite) the dataset's: choose another --out")
        if out.exists() and not out.is_dir():
            raise RunFolderError(f"{out}: exists and is not a folder")
        entries = sorted(p.name for p in out.iterdir()) if out.is_dir() else []
        if entries:
            if overwrite:
                if looks_like_dataset(out):
                    raise RunFolderError(f"{out}: holds a dataset (calib/ or labels/2d); not overwritten")
            elif resume:
                cls._check_resume(out, manifest)
            else:
                raise RunFolderError(f"{out}: not empty ({', '.join(entries[:3])}"
                                     f"{', ...' if len(entries) > 3 else ''}); pass --resume to finish that run "
                                     "or --overwrite to replace its results")
        return cls(out, manifest, fresh=not (entries and resume), overwrite=bool(entries and overwrite))

    @staticmethod
    def _check_resume(out: Path, manifest: dict) -> None:
        path = out / MANIFEST
        try:
            previous = json.loads(path.read_text())
        except FileNotFoundError:
            raise RunFolderError(f"{path}: missing, so {out} is not a run that can be resumed; pass --overwrite "
                                 "to replace its content or choose another --out") from None
        except (OSError, ValueError) as exc:
            raise RunFolderError(f"{path}: unreadable ({exc}); pass --overwrite to start again") from None
        if not isinstance(previous, dict):
            raise RunFolderError(f"{path}: not a run manifest; pass --overwrite to start again")
        for key, value in manifest.items():
            if previous.get(key) != value:
                raise RunFolderError(f"{path}: cannot resume: its '{key}' is {previous.get(key)!r}, this run's is "
                                     f"{value!r} (pass --overwrite to start again)")

    def prepare(self, configs: dict) -> None:
        """Make the folder: remove a previous run's entries (``overwrite``), write the manifest and the
        configs (``<name>.yaml``), clear what an interrupted write left behind."""
        from pedx_graph.config import save_config

        self.path.mkdir(parents=True, exist_ok=True)
        if self.overwrite:
            self._remove_previous()
        if self.fresh:
            atomic_write_bytes(self.path / MANIFEST, json_bytes(self.manifest))
        for name, cfg in configs.items():
            save_config(cfg, self.path / f"{name}.yaml")
        self.clean_interrupted_writes()

    def _remove_previous(self) -> None:
        for name in OWNED:
            entry = self.path / name
            if entry.is_dir() and not entry.is_symlink():
                shutil.rmtree(entry)
            elif entry.exists() or entry.is_symlink():
                entry.unlink()
        smpl = self.path / "labels" / "3d" / "smpl"
        if smpl.is_dir():
            shutil.rmtree(smpl)
        for empty in (self.path / "labels" / "3d", self.path / "labels"):
            if empty.is_dir() and not any(empty.iterdir()):
                empty.rmdir()

    # --- markers ---------------------------------------------------------------------------------------------
    def marker_path(self, key: tuple[str, str]) -> Path:
        return self.path / DONE / marker_name(key)

    def writing_path(self, key: tuple[str, str]) -> Path:
        marker = self.marker_path(key)
        return marker.with_name(marker.stem + ".writing")

    def completed(self) -> set[tuple[str, str]]:
        """Tracks with a completion marker."""
        done = set()
        base = self.path / DONE
        if not base.is_dir():
            return done
        for path in base.glob("*/*.json"):
            marker = self.read_marker_file(path)
            if marker is not None:
                done.add((marker["sequence"], marker["tracking_id"]))
        return done

    @staticmethod
    def read_marker_file(path: Path) -> dict | None:
        try:
            marker = json.loads(path.read_text())
        except (OSError, ValueError) as exc:
            log.warning("%s: unreadable completion marker (%s); the track is run again", path, exc)
            return None
        if not isinstance(marker, dict) or marker.get("status") != "done" or "records" not in marker:
            log.warning("%s: not a completion marker; the track is run again", path)
            return None
        return marker

    def read_marker(self, key: tuple[str, str]) -> dict | None:
        path = self.marker_path(key)
        return self.read_marker_file(path) if path.is_file() else None

    def clean_interrupted_writes(self) -> int:
        """Remove the files of tracks whose writing was cut (a ``.writing`` list without its marker, e.g.
        after a SIGKILL): they are run again.  Returns how many tracks were cleaned."""
        base = self.path / DONE
        n = 0
        for listing in sorted(base.glob("*/*.writing")) if base.is_dir() else []:
            marker = listing.with_suffix(".json")
            if not marker.is_file():
                try:
                    files = json.loads(listing.read_text())
                except (OSError, ValueError):
                    files = []
                for rel in files if isinstance(files, list) else []:
                    self._remove_result(rel)
                n += 1
            listing.unlink()
        return n

    def _remove_result(self, rel: str) -> None:
        path = (self.path / rel).resolve()
        if _within(path, self.path.resolve()) and (path.is_file() or path.is_symlink()):
            path.unlink()

    # --- one track -------------------------------------------------------------------------------------------
    def commit(self, outcome: TaskOutcome) -> None:
        """Write a finished track: its files (each atomically), then its completion marker.  On any failure
        the files already written are removed and the exception propagates (the caller records the track as
        failed; the other tracks are unaffected)."""
        output = outcome.output
        rels = [rel for rel, _ in output.files]
        for rel in rels:
            if Path(rel).is_absolute() or ".." in Path(rel).parts:
                raise ValueError(f"result path {rel!r} leaves the results folder")
        listing = self.writing_path(outcome.key)
        written: list[str] = []
        try:
            atomic_write_bytes(listing, json_bytes(rels))
            for rel, data in output.files:
                atomic_write_bytes(self.path / rel, data)
                written.append(rel)
            marker = {"status": "done", "sequence": outcome.sequence, "tracking_id": outcome.tracking_id,
                      "frames": output.frames, "files": rels, "records": output.records}
            atomic_write_bytes(self.marker_path(outcome.key), json_bytes(marker))
        except BaseException:
            for rel in written:
                try:
                    self._remove_result(rel)
                except OSError:
                    pass
            raise
        finally:
            try:
                listing.unlink()
            except OSError:
                pass

    # --- timings -------------------------------------------------------------------------------------------
    def append_timing(self, key: tuple[str, str], timing: dict) -> None:
        """Append one track's timings (a JSON line) to ``timings.jsonl``."""
        line = json.dumps(to_jsonable({"sequence": key[0], "tracking_id": key[1], **timing}))
        with open(self.path / TIMINGS, "a", encoding="utf-8") as fh:
            fh.write(line + "\n")

    def read_timings(self) -> dict[tuple[str, str], dict]:
        """Track -> its latest timings line (a torn last line is skipped)."""
        out: dict[tuple[str, str], dict] = {}
        path = self.path / TIMINGS
        if not path.is_file():
            return out
        for line in path.read_text(encoding="utf-8").splitlines():
            try:
                entry = json.loads(line)
                out[(entry["sequence"], entry["tracking_id"])] = entry
            except (ValueError, KeyError, TypeError):
                continue
        return out

    # --- the summary -----------------------------------------------------------------------------------------
    def write_summary(self, head: dict, tracks: Iterable[dict], tail: dict) -> Path:
        """Write ``summary.json`` atomically: ``head``'s keys, then ``tracks`` (streamed one record at a
        time, never all in memory), then ``tail``'s keys."""
        path = self.path / SUMMARY
        with atomic_writer(path) as fh:
            fh.write(b"{\n")
            for key, value in head.items():
                fh.write(_member(key, value))
            fh.write(b' "tracks": [')
            first = True
            for record in tracks:
                fh.write((b"\n  " if first else b",\n  ") + json.dumps(to_jsonable(record)).encode("utf-8"))
                first = False
            fh.write(b"\n ]" if not first else b"]")
            for key, value in tail.items():
                fh.write(b",\n" + _member(key, value).rstrip(b",\n"))
            fh.write(b"\n}\n")
        return path


def _member(key: str, value) -> bytes:
    return f" {json.dumps(key)}: {json.dumps(to_jsonable(value))},\n".encode("utf-8")
