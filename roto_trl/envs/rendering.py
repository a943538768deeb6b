"""Offscreen RGB frames of one world of a batched env, with the active contact sensors lit.

MuJoCo picks its OpenGL backend from ``MUJOCO_GL`` when ``mujoco`` is first imported. On a
machine without a display set ``MUJOCO_GL=egl`` (Mesa's software EGL; Debian packages
``libegl1 libgl1-mesa-dri``) or ``MUJOCO_GL=osmesa`` (``libosmesa6``) before Python imports
mujoco; ``python -m roto_trl.record`` does so itself.
"""

from __future__ import annotations

import os

import mujoco
import numpy as np

from roto_trl.envs.batched_mujoco import FULL_PHYSICS

DEFAULT_CAMERA = "roto:side"  # every scene has it (shadow_hand.xml, find.xml)
LIT_RGBA = np.array([1.0, 0.85, 0.1, 1.0], dtype=np.float32)  # an active sensor's colour
GL_HELP = (
    "set MUJOCO_GL=egl (or osmesa) before Python starts and install Mesa "
    "(Debian: apt-get install libegl1 libgl1-mesa-dri libosmesa6)"
)


class SceneRenderer:
    """Renders single worlds of a model from a named camera.

    Args:
        model: the compiled model (its ``<visual><global offwidth offheight>`` bound the size).
        camera: name of a camera in the scene.
        width, height: frame size in pixels.
    """

    def __init__(self, model: mujoco.MjModel, camera: str, width: int, height: int) -> None:
        if mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_CAMERA, camera) < 0:
            cams = [model.camera(i).name for i in range(model.ncam)]
            raise ValueError(f"no camera {camera!r} in the scene; cameras: {cams}")
        if width > model.vis.global_.offwidth or height > model.vis.global_.offheight:
            raise ValueError(
                f"frame {width}x{height} exceeds the scene's offscreen buffer "
                f"{model.vis.global_.offwidth}x{model.vis.global_.offheight}"
            )
        try:
            self._renderer = mujoco.Renderer(model, height=height, width=width)
        except Exception as err:  # GL errors come as several types, all with the same fix
            backend = os.environ.get("MUJOCO_GL", "<unset: glfw, needs a display>")
            raise RuntimeError(f"no OpenGL context (MUJOCO_GL={backend}: {err}); {GL_HELP}") from err
        self.model = model
        self.camera = camera
        self._data = mujoco.MjData(model)

    def frame(
        self, state: np.ndarray, mocap_pos: np.ndarray, lit_bodies: list[int] | tuple[int, ...] = ()
    ) -> np.ndarray:
        """The world in full-physics ``state`` [nstate] with ``mocap_pos`` [nmocap, 3].

        Geoms of the bodies in ``lit_bodies`` are drawn in ``LIT_RGBA``.

        Returns:
            ``[height, width, 3]`` uint8 RGB.
        """
        m, d = self.model, self._data
        mujoco.mj_setState(m, d, state, FULL_PHYSICS)
        d.mocap_pos[:] = mocap_pos
        mujoco.mj_forward(m, d)
        self._renderer.update_scene(d, camera=self.camera)
        if len(lit_bodies):
            lit = set(lit_bodies)
            scene = self._renderer.scene
            for geom in scene.geoms[: scene.ngeom]:
                if geom.objtype == mujoco.mjtObj.mjOBJ_GEOM and int(m.geom_bodyid[geom.objid]) in lit:
                    geom.rgba[:] = LIT_RGBA
                    geom.emission = 0.6
        return self._renderer.render()

    def close(self) -> None:
        self._renderer.close()
