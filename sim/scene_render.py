"""Renders rig scenes: the sphere, its mount, lights and material in VTK, then background and camera.

    from sim.scene import load_scene
    from sim.scene_render import SceneRenderer
    sr = SceneRenderer("Texture_3_color.png", load_scene("sim/scenes/train.json"))
    rgb, params = sr.frame((x, y, z), numpy.random.default_rng([seed, i]))   # params: the frame's draw

The VTK pass draws RGBA (alpha 0 where nothing is drawn) through the frame's
pinhole camera (focal length, distance, the sphere's offset from the principal
point) with a margin for the lens; sim/lens.py applies the lens distortion;
sim/scene_background.py fills the background; sim/scene_effects.py does the
camera's optics, sensor and encoding. params["circle"] is the sphere's outline
in the undistorted frame (conventions' continuous pixels).
"""
import json

from sim.render import Light, Renderer
from sim.scene import draw, margin_for
from sim.scene_background import make_background
from sim.scene_effects import finish
from sim.scene_mount import Mount


class SceneRenderer:
    """One VTK renderer with the scene's mount; create once per process, call `frame` many times."""

    def __init__(self, texture, scene, gl=None):
        self.scene = scene
        self.camera = scene.camera
        self.renderer = Renderer(texture, scene.camera, alpha=True, margin=margin_for(scene), gl=gl)
        self.mount = Mount(self.renderer)
        self._background = (None, None)  # (draw, image) of the last frame: a fixed rig's is made once

    def render(self, pose, params):
        """uint8 RGB frame of the sphere at `pose` (degrees) with the values of draw `params`."""
        cam = self.camera
        c = params["camera"]
        self.renderer.set_material(**params["sphere"])
        self.mount.set(params["mount"], cam.radius_mm)
        lights = tuple(Light(tuple(l["direction"]), l["intensity"], tuple(l["color"])) for l in params["lights"])
        rgba = self.renderer.render(pose, lights=lights, background=(0, 0, 0), offset_px=params["offset_px"],
                                    scale=c["focal_px"] / cam.focal_px, distance_mm=c["distance_mm"],
                                    principal=c["principal_px"], distortion=c["distortion"])
        key = json.dumps(params["background"], sort_keys=True)
        if self._background[0] != key:
            self._background = (key, make_background(params["background"], self.scene.background,
                                                     self.scene.photos, cam.width, cam.height))
        bg = self._background[1]  # read only from here on
        return finish(rgba, bg, params["image"], c["principal_px"])

    def frame(self, pose, rng):
        """(uint8 RGB frame, its draw) at `pose` with values drawn from numpy Generator `rng`."""
        params = draw(self.scene, rng)
        return self.render(pose, params), params

    def close(self):
        self.renderer.close()
