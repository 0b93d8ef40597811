"""Rewrite the generated benchmark blocks of docs/results.md and docs/detections.md from benchmarks/results.

    python tools/gen_benchmark_docs.py
"""
from __future__ import annotations

import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from pedx_graph.eval.benchmark_tables import (DETECTIONS_BEGIN, DETECTIONS_END, DETECTIONS_PEDX_BEGIN,  # noqa: E402
                                              DETECTIONS_PEDX_END, DETECTIONS_PEDX_FOLDER, IDENTITY_FIXES_BEGIN,
                                              FRAME_RATES_BEGIN, FRAME_RATES_END, IDENTITY_FIXES_END,
                                              IMAGE_FRAME_BEGIN, IMAGE_FRAME_END, KEYPOINT_CALIBRATION_BEGIN,
                                              KEYPOINT_CALIBRATION_END, PIXEL_SCALE_BEGIN,
                                              PIXEL_SCALE_END, benchmark_block, detections_block,
                                              frame_rates_block, identity_fixes_block, image_frame_block,
                                              keypoint_calibration_block,
                                              pixel_scale_block, replace_block)
from pedx_graph.utils import atomic_write_text  # noqa: E402


def main() -> int:
    results = ROOT / "benchmarks" / "results"
    path = ROOT / "docs" / "results.md"
    atomic_write_text(path, replace_block(path.read_text(), benchmark_block(results)))
    path = ROOT / "docs" / "detections.md"
    text = path.read_text()
    blocks = ((DETECTIONS_BEGIN, DETECTIONS_END, lambda: detections_block(results)),
              (DETECTIONS_PEDX_BEGIN, DETECTIONS_PEDX_END,
               lambda: detections_block(ROOT / DETECTIONS_PEDX_FOLDER, DETECTIONS_PEDX_FOLDER,
                                        DETECTIONS_PEDX_BEGIN, DETECTIONS_PEDX_END)),
              (IDENTITY_FIXES_BEGIN, IDENTITY_FIXES_END, lambda: identity_fixes_block(results)),
              (IMAGE_FRAME_BEGIN, IMAGE_FRAME_END, lambda: image_frame_block(results)),
              (PIXEL_SCALE_BEGIN, PIXEL_SCALE_END, lambda: pixel_scale_block(results)),
              (FRAME_RATES_BEGIN, FRAME_RATES_END, lambda: frame_rates_block(results)),
              (KEYPOINT_CALIBRATION_BEGIN, KEYPOINT_CALIBRATION_END, lambda: keypoint_calibration_block(results)))
    for begin, end, block in blocks:
        if begin not in text:
            raise SystemExit(f"{path}: no {begin} marker")
        text = replace_block(text, block(), begin, end)
    atomic_write_text(path, text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
