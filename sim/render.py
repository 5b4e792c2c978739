"""Offscreen VTK renderer of the textured sphere, following conventions.md exactly.

Pipeline (built once per Renderer, reused for every pose):

    uv_sphere (sim/mesh.py) -> vtkPolyData (points, normals, tcoords, triangles)
      -> vtkPolyDataMapper -> vtkActor (user transform = R(pose), textured)
      -> vtkRenderer (scene lights, background) -> offscreen render window
      -> vtkWindowToImageFilter -> numpy RGB (rows top to bottom)

No display is needed: the render window is Mesa's OSMesa (software, default)
or EGL (`SPHEREPOSE_GL=egl`). No interactor is ever created.

Geometry (conventions.md): the camera sits at (0, 0, D) looking at the
origin with view-up +Y; its vertical view angle is 2 atan(H p / 2 f), so a
world point lands at u = W/2 + (f/p) X/(D - Z), v = H/2 - (f/p) Y/(D - Z).
The sphere's user transform is R = Rz(z) Ry(y) Rx(x) (sim/pose.py), so body
points map to world points exactly as p_W = R p_B.

Antialiasing and texture filtering (speed matters: software OpenGL):
- no multisampling by default (`multisamples=0`): MSAA 4x triples the frame
  time under llvmpipe and only softens the silhouette, which is already
  within a pixel; pass multisamples=4 for nicer pictures;
- the texture is sampled bilinearly, after being reduced once (area
  averaging, on the CPU) to about 1.25 texels per image pixel at the sphere's
  centre for this camera (2048 -> 1140 wide at the reference camera). That
  is what mipmapping would pick at the centre, without its per-fragment cost
  (trilinear mipmapping costs +80 %); `mipmap=True` turns it on.
"""
import math
import os
from dataclasses import dataclass

import cv2
import numpy as np
from PIL import Image

# Explicit VTK modules, no `import vtk` (loads only what is used).
from vtkmodules.util.numpy_support import numpy_to_vtk, numpy_to_vtkIdTypeArray, vtk_to_numpy
from vtkmodules.vtkCommonCore import vtkPoints
from vtkmodules.vtkCommonDataModel import vtkCellArray, vtkImageData, vtkPolyData
from vtkmodules.vtkCommonMath import vtkMatrix4x4
from vtkmodules.vtkCommonTransforms import vtkTransform
from vtkmodules.vtkRenderingCore import (vtkActor, vtkLight, vtkPolyDataMapper, vtkRenderer,
                                         vtkTexture, vtkWindowToImageFilter)
import vtkmodules.vtkRenderingOpenGL2  # noqa: F401  (registers the OpenGL2 backend)
from vtkmodules.vtkRenderingOpenGL2 import vtkEGLRenderWindow, vtkOSOpenGLRenderWindow

from sim.camera import Camera
from sim.mesh import uv_sphere
from sim.pose import euler_to_matrix

# Default background: a dark neutral grey, clearly apart from black, white and
# the texture colours (green, blue) by more than the preprocessing threshold
# (fg_threshold 40 on max |channel difference|), so sphere-crop-v1 finds the sphere.
DEFAULT_BACKGROUND = (64, 64, 70)

# Mesh resolution: 45 latitude rings x 90 longitude segments (4 deg facets). At
# the reference camera the sphere is 267 px across; the chord sag of a 4 deg
# facet is r (1 - cos 2 deg) = 0.08 px, far below the 1.5 px conventions
# tolerance, and the vertex load is a quarter of the 2 deg mesh (-40 % time).
DEFAULT_MESH = (45, 90)

# Texture reduction target: texels per image pixel at the sphere's centre.
TEXELS_PER_PIXEL = 1.25


@dataclass(frozen=True)
class Light:
    """A directional scene light: `direction` points from the sphere toward the light (world frame)."""
    direction: tuple = (0.0, 0.0, 1.0)
    intensity: float = 1.0
    color: tuple = (1.0, 1.0, 1.0)


# A key light high on the camera's left, a weaker fill low on its right, and a
# faint rim from behind-above; together with the ambient term every visible
# point of the sphere keeps at least ~35 % of its texture brightness.
KEY_LIGHT = Light(direction=(-0.45, 0.55, 1.0), intensity=0.65)
FILL_LIGHT = Light(direction=(0.6, -0.25, 1.0), intensity=0.35)
RIM_LIGHT = Light(direction=(0.0, 0.8, -0.6), intensity=0.2)
DEFAULT_LIGHTS = (KEY_LIGHT, FILL_LIGHT, RIM_LIGHT)

# Surface material of the sphere (Phong terms of vtkProperty).
AMBIENT = 0.45
DIFFUSE = 0.6
SPECULAR = 0.08
SPECULAR_POWER = 20.0

GL_BACKENDS = ("osmesa", "egl")


class TextureError(ValueError):
    """A texture file that cannot be used; the message names the file."""


def load_texture(path):
    """RGB uint8 array [H, W, 3] of an equirectangular texture (width = 2 x height)."""
    try:
        with Image.open(path) as im:
            rgb = np.asarray(im.convert("RGB"), dtype=np.uint8)
    except FileNotFoundError:
        raise TextureError(f"{path}: texture file not found") from None
    except OSError as e:
        raise TextureError(f"{path}: cannot read texture image: {e}") from None
    h, w = rgb.shape[:2]
    if w != 2 * h:
        raise TextureError(f"{path}: texture is {w} x {h}; an equirectangular texture is "
                           f"twice as wide as high (e.g. 2048 x 1024)")
    return rgb


def reduced_texture(rgb, camera):
    """The texture area-averaged down to ~TEXELS_PER_PIXEL texels per image pixel at the sphere's centre.

    Near the centre one degree of longitude spans f_px * r / (D - r) * pi / 180 pixels.
    Textures already at or below that density are returned unchanged.
    """
    h, w = rgb.shape[:2]
    px_per_deg = camera.focal_px * camera.radius_mm / (camera.distance_mm - camera.radius_mm) * math.pi / 180.0
    want_w = int(math.ceil(TEXELS_PER_PIXEL * px_per_deg * 360.0 / 2.0)) * 2
    if want_w >= w:
        return rgb
    return cv2.resize(rgb, (want_w, want_w // 2), interpolation=cv2.INTER_AREA)


def lights_from_json(values, source="lights"):
    """Lights from a JSON list of {"direction": [x, y, z], "intensity": i, "color": [r, g, b]}."""
    if not isinstance(values, list):
        raise ValueError(f"{source}: expected a JSON list of lights")
    lights = []
    for i, item in enumerate(values):
        if not isinstance(item, dict):
            raise ValueError(f"{source}: light {i} is not an object")
        unknown = set(item) - {"direction", "intensity", "color"}
        if unknown:
            raise ValueError(f"{source}: light {i}: unknown key {sorted(unknown)[0]!r} "
                             f"(valid keys: direction, intensity, color)")
        try:
            d = tuple(float(v) for v in item.get("direction", (0, 0, 1)))
            inten = float(item.get("intensity", 1.0))
            col = tuple(float(v) for v in item.get("color", (1, 1, 1)))
        except (TypeError, ValueError):
            raise ValueError(f"{source}: light {i}: direction, intensity and color must be numbers") from None
        if len(d) != 3 or len(col) != 3 or not np.any(d):
            raise ValueError(f"{source}: light {i}: direction and color need 3 values, direction non-zero")
        lights.append(Light(d, inten, col))
    return tuple(lights)


def lights_to_json(lights):
    return [{"direction": list(l.direction), "intensity": l.intensity, "color": list(l.color)} for l in lights]


def _make_render_window(backend):
    """An offscreen OpenGL window that needs no display (Mesa OSMesa or EGL)."""
    if backend not in GL_BACKENDS:
        raise ValueError(f"unknown GL backend {backend!r}; choose one of {', '.join(GL_BACKENDS)}")
    window = vtkOSOpenGLRenderWindow() if backend == "osmesa" else vtkEGLRenderWindow()
    window.SetOffScreenRendering(1)
    return window


def _sphere_polydata(radius_mm, n_lat, n_lon):
    """vtkPolyData of the shared UV sphere (sim/mesh.py), with normals and texture coordinates."""
    verts, normals, tcoords, tris = uv_sphere(radius_mm, n_lat, n_lon)
    points = vtkPoints()
    points.SetData(numpy_to_vtk(np.ascontiguousarray(verts, dtype=np.float32), deep=True))
    cells = vtkCellArray()
    offsets = np.arange(0, 3 * len(tris) + 1, 3, dtype=np.int64)
    cells.SetData(numpy_to_vtkIdTypeArray(offsets, deep=True),
                  numpy_to_vtkIdTypeArray(np.ascontiguousarray(tris.ravel(), dtype=np.int64), deep=True))
    poly = vtkPolyData()
    poly.SetPoints(points)
    poly.SetPolys(cells)
    vn = numpy_to_vtk(np.ascontiguousarray(normals, dtype=np.float32), deep=True)
    vn.SetName("Normals")
    poly.GetPointData().SetNormals(vn)
    tc = numpy_to_vtk(np.ascontiguousarray(tcoords, dtype=np.float32), deep=True)
    tc.SetName("TCoords")
    poly.GetPointData().SetTCoords(tc)
    return poly


def _texture_image(rgb):
    """vtkImageData of an RGB array; VTK images start at the bottom row (t = 0, the south pole)."""
    h, w = rgb.shape[:2]
    img = vtkImageData()
    img.SetDimensions(w, h, 1)
    scalars = numpy_to_vtk(np.ascontiguousarray(np.flipud(rgb)).reshape(-1, 3), deep=True)
    scalars.SetName("RGB")
    img.GetPointData().SetScalars(scalars)
    return img


def _matrix4(R):
    m = vtkMatrix4x4()
    for i in range(3):
        for j in range(3):
            m.SetElement(i, j, float(R[i][j]))
    return m


class Renderer:
    """Renders the textured sphere at any pose; create once per process, call `render` many times.

    texture: RGB uint8 array [H, W, 3] or a path to an equirectangular image.
    camera: sim.camera.Camera. lights: sequence of Light (empty with lit=False: flat texture colours).
    background: (R, G, B) 0-255. multisamples: MSAA samples (0 = off). gl: 'osmesa' or 'egl'.
    """

    def __init__(self, texture, camera=None, *, lights=DEFAULT_LIGHTS, background=DEFAULT_BACKGROUND,
                 lit=True, mesh=DEFAULT_MESH, multisamples=0, mipmap=False, reduce_texture=True, gl=None,
                 margin=None, alpha=False):
        self.camera = camera or Camera()
        # Pixels drawn beyond the frame on each side, for the lens distortion's remap (sim/lens.py);
        # None: what the camera's own distortion needs (0 without distortion).
        if margin is None:
            from sim.lens import margin_px
            margin = margin_px(self.camera.width, self.camera.height, self.camera.focal_px,
                               self.camera.principal, self.camera.distortion)
        self.margin = int(margin)
        self.alpha = bool(alpha)
        self.lights = tuple(lights)
        self.background = tuple(int(c) for c in background)
        rgb = load_texture(texture) if isinstance(texture, (str, os.PathLike)) else np.asarray(texture, np.uint8)
        if rgb.ndim != 3 or rgb.shape[2] != 3:
            raise TextureError("texture must be an RGB image [H, W, 3]")
        gl = gl or os.environ.get("SPHEREPOSE_GL", "osmesa")
        if reduce_texture and not mipmap:
            rgb = reduced_texture(rgb, self.camera)

        # Geometry: the shared UV sphere at the camera's sphere radius.
        mapper = vtkPolyDataMapper()
        mapper.SetInputData(_sphere_polydata(self.camera.radius_mm, *mesh))
        mapper.ScalarVisibilityOff()

        # Map texture coordinates: the equirectangular image, sampled bilinearly (trilinear from
        # mipmaps only with mipmap=True), clamped at the seam.
        tex = vtkTexture()
        tex.SetInputData(_texture_image(rgb))
        tex.InterpolateOn()
        tex.SetMipmap(bool(mipmap))
        tex.RepeatOff()
        tex.EdgeClampOn()
        tex.SetColorModeToDirectScalars()

        # Sphere actor: body -> world through its user transform R(pose).
        self._actor = vtkActor()
        self._actor.SetMapper(mapper)
        self._actor.SetTexture(tex)
        prop = self._actor.GetProperty()
        prop.SetColor(1.0, 1.0, 1.0)
        # The sphere is closed: back faces are never seen. Culling them before
        # rasterisation halves the frame time under software OpenGL.
        prop.BackfaceCullingOn()
        if lit:
            prop.SetAmbient(AMBIENT)
            prop.SetDiffuse(DIFFUSE)
            prop.SetSpecular(SPECULAR)
            prop.SetSpecularPower(SPECULAR_POWER)
        else:
            prop.LightingOff()  # flat: pixel colour = texture colour (used by the conventions test)
        self._transform = vtkTransform()
        self._actor.SetUserTransform(self._transform)

        # Scene: our own lights only, no automatic headlight.
        self._renderer = vtkRenderer()
        self._renderer.AutomaticLightCreationOff()
        self._renderer.AddActor(self._actor)
        self._vtk_lights = []

        # Camera per conventions: at (0, 0, D), looking at the origin, view-up +Y.
        self._vcam = self._renderer.GetActiveCamera()
        self._vcam.SetPosition(0.0, 0.0, self.camera.distance_mm)
        self._vcam.SetFocalPoint(0.0, 0.0, 0.0)
        self._vcam.SetViewUp(0.0, 1.0, 0.0)
        r, d = self.camera.radius_mm, self.camera.distance_mm
        self._vcam.SetClippingRange(max(d - 2.0 * r, 0.05 * d), d + 2.0 * r)

        # Offscreen window of exactly W x H pixels.
        self._window = _make_render_window(gl)
        self._window.SetMultiSamples(int(multisamples))
        self._window.AddRenderer(self._renderer)
        self._window.SetSize(self.camera.width + 2 * self.margin, self.camera.height + 2 * self.margin)
        if self.alpha:
            # Background pixels read back with alpha 0: a scene composites its own background there.
            self._window.SetAlphaBitPlanes(1)
            self._renderer.SetBackgroundAlpha(0.0)

        # Capture: read the back buffer of the frame just rendered, RGB (or RGBA) only.
        self._capture = vtkWindowToImageFilter()
        self._capture.SetInput(self._window)
        if self.alpha:
            self._capture.SetInputBufferTypeToRGBA()
        else:
            self._capture.SetInputBufferTypeToRGB()
        self._capture.ReadFrontBufferOff()
        self._capture.ShouldRerenderOff()

    def _set_lights(self, lights):
        if len(lights) != len(self._vtk_lights):
            self._renderer.RemoveAllLights()
            self._vtk_lights = []
            for _ in lights:
                light = vtkLight()
                light.SetLightTypeToSceneLight()
                light.PositionalOff()
                self._renderer.AddLight(light)
                self._vtk_lights.append(light)
        for vl, l in zip(self._vtk_lights, lights):
            d = np.asarray(l.direction, float)
            d = d / np.linalg.norm(d)
            vl.SetFocalPoint(0.0, 0.0, 0.0)
            vl.SetPosition(*(d * 10.0 * self.camera.distance_mm))
            vl.SetIntensity(float(l.intensity))
            vl.SetColor(*l.color)

    def add_actor(self, actor):
        """Another object of the scene (e.g. a mount); the clipping range then covers a deeper scene."""
        self._renderer.AddActor(actor)
        self._deep_scene = True

    def set_material(self, ambient, diffuse, specular, specular_power):
        """The sphere's Phong terms (vtkProperty) for the frames that follow."""
        prop = self._actor.GetProperty()
        prop.SetAmbient(float(ambient))
        prop.SetDiffuse(float(diffuse))
        prop.SetSpecular(float(specular))
        prop.SetSpecularPower(float(specular_power))

    def render(self, pose, *, lights=None, background=None, offset_px=(0.0, 0.0), scale=1.0,
               distance_mm=None, principal=None, distortion=None):
        """RGB uint8 image [H, W, 3] (row 0 at the top) of the sphere at pose (x, y, z) degrees.

        lights/background override the renderer's for this frame only. offset_px moves the
        sphere's image by (du, dv) pixels (right, down) from the principal point (a shift of the
        pinhole image's principal point); scale multiplies the focal length; distance_mm moves the
        camera. principal and distortion override the camera's lens (principal point (u0, v0) in
        continuous pixels, OpenCV coefficients), applied by sim/lens.py after the pinhole render.
        With alpha=True at construction the image is RGBA, alpha 0 on the background.
        Every setting is written on every call, so a frame never depends on the frames before it.
        """
        cam = self.camera
        self._transform.SetMatrix(_matrix4(euler_to_matrix(*pose)))
        self._set_lights(self.lights if lights is None else lights)
        bg = self.background if background is None else background
        self._renderer.SetBackground(*(float(c) / 255.0 for c in bg))
        m = self.margin
        win_w, win_h = cam.width + 2 * m, cam.height + 2 * m
        # Intrinsics: focal length (scale) and principal point (offset) of this frame.
        f_px = cam.focal_px * float(scale)
        self._vcam.SetViewAngle(math.degrees(2.0 * math.atan(win_h / (2.0 * f_px))))
        u0, v0 = cam.principal if principal is None else principal
        du = u0 + float(offset_px[0]) - cam.width / 2.0
        dv = v0 + float(offset_px[1]) - cam.height / 2.0
        self._vcam.SetWindowCenter(-2.0 * du / win_w, 2.0 * dv / win_h)
        d = cam.distance_mm if distance_mm is None else float(distance_mm)
        self._vcam.SetPosition(0.0, 0.0, d)
        r = cam.radius_mm
        if getattr(self, "_deep_scene", False):
            self._vcam.SetClippingRange(0.2 * d, 4.0 * d)
        else:
            self._vcam.SetClippingRange(max(d - 2.0 * r, 0.05 * d), d + 2.0 * r)

        self._window.Render()
        self._capture.Modified()
        self._capture.Update()
        out = self._capture.GetOutput()
        w, h, _ = out.GetDimensions()
        ch = 4 if self.alpha else 3
        img = np.flipud(vtk_to_numpy(out.GetPointData().GetScalars()).reshape(h, w, ch))
        dist = cam.distortion if distortion is None else tuple(distortion)
        if any(dist):
            from sim.lens import distort
            return distort(np.ascontiguousarray(img), f_px, (u0, v0), dist, margin=m)
        if m:
            img = img[m:m + cam.height, m:m + cam.width]
        return np.ascontiguousarray(img)

    def close(self):
        """Release the OpenGL context (also done at exit)."""
        self._window.Finalize()
