"""Writing rendered frames as video files, and reading them back."""

from __future__ import annotations

from pathlib import Path

import av
import numpy as np

FPS = 60  # one frame per control step: real time


def write_mp4(path: Path, frames: list[np.ndarray], fps: int = FPS) -> None:
    """Encode RGB frames ``[H, W, 3]`` uint8 as H.264 in ``path``."""
    height, width = frames[0].shape[:2]
    with av.open(str(path), mode="w") as container:
        stream = container.add_stream("libx264", rate=fps)
        stream.width, stream.height = width - width % 2, height - height % 2
        stream.pix_fmt = "yuv420p"
        for rgb in frames:
            frame = av.VideoFrame.from_ndarray(rgb[: stream.height, : stream.width], format="rgb24")
            container.mux(stream.encode(frame))
        container.mux(stream.encode())


def read_mp4(path: Path) -> list[np.ndarray]:
    """The RGB frames ``[H, W, 3]`` uint8 of a video file, in order."""
    with av.open(str(path)) as container:
        return [frame.to_ndarray(format="rgb24") for frame in container.decode(video=0)]
