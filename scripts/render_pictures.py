"""Render the README's picture of each task into docs/<task>.png (the default pose, sensors lit).

.venv/bin/python scripts/render_pictures.py
"""

import os

os.environ.setdefault("MUJOCO_GL", "egl")  # before mujoco is imported

from pathlib import Path

from PIL import Image

from roto_trl import TASKS, make_env

DOCS = Path(__file__).resolve().parent.parent / "docs"


def main() -> None:
    for task in TASKS:
        env = make_env(task, 1, seed=0)
        base = env.base_env
        td = env.reset()
        action = base.default_pose_action().unsqueeze(0)
        for _ in range(30):  # let the objects settle into the hand
            td = env.step(td.set("action", action))["next"]
        path = DOCS / f"{task}.png"
        Image.fromarray(base.render(0)).save(path)
        print(f"{task}: {path}")
        env.close()


if __name__ == "__main__":
    main()
