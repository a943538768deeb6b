"""A strip of frames taken evenly from a video, each titled with its time: a figure for the docs.

    .venv/bin/python scripts/frame_strip.py runs/baoding_ppo/<run>/videos/eval-latest-s3.mp4 \\
        --frames 6 --start 2 --end 6 --out docs/baoding_rotation.png

The videos of ``evaluate.py video=true`` and ``roto_trl.record`` run at one frame per control
step (60 per second), so frame i is at i / 60 s.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from roto_trl.analysis.plots import save_figure
from roto_trl.utils.video import FPS, read_mp4


def strip_indices(n_frames: int, count: int, start: float, end: float | None) -> list[int]:
    """``count`` frame indices evenly from ``start`` to ``end`` seconds (the video's end by
    default), both included; a ``ValueError`` when the window holds fewer frames or lies outside."""
    last = n_frames - 1
    first, final = round(start * FPS), last if end is None else round(end * FPS)
    if not 0 <= first < final <= last:
        window = f"--start {start:g} s" + ("" if end is None else f" and --end {end:g} s")
        raise ValueError(f"{window} must lie in the video's 0-{last / FPS:.2f} s, the start first")
    if final - first + 1 < count:
        raise ValueError(f"the window holds {final - first + 1} frames, fewer than --frames {count}")
    return [int(i) for i in np.linspace(first, final, count).round()]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("video", type=Path, help="an .mp4 of evaluate.py video=true or roto_trl.record")
    parser.add_argument("--frames", type=int, default=6, help="how many frames (default 6)")
    parser.add_argument("--start", type=float, default=0.0, help="from this second (default 0)")
    parser.add_argument("--end", type=float, default=None, help="to this second (default: the end)")
    parser.add_argument("--out", type=Path, required=True, help="the .png to write")
    args = parser.parse_args(argv)
    if not args.video.is_file():
        raise SystemExit(f"frame_strip: {args.video} is not a file; give the .mp4 to take frames from")
    if args.frames < 2:
        raise SystemExit(f"frame_strip: --frames must be 2 or more, got {args.frames}")
    frames = read_mp4(args.video)
    try:
        indices = strip_indices(len(frames), args.frames, args.start, args.end)
    except ValueError as err:
        raise SystemExit(f"frame_strip: {err}") from None
    height, width = frames[0].shape[:2]
    fig, axes = plt.subplots(1, len(indices), figsize=(2.4 * len(indices), 2.4 * height / width + 0.4))
    for ax, i in zip(axes, indices, strict=True):
        ax.imshow(frames[i])
        ax.set_title(f"t = {i / FPS:.2f} s", fontsize=9)
        ax.axis("off")
    print(save_figure(fig, args.out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
