"""Off-screen OpenGL through OSMesa: the only module of vrsim that imports OpenGL.

Imported by `vrsim_cli.render.open_renderer` only when frames are asked for. It uses the
fixed-function pipeline (Mesa's llvmpipe gives a 4.5 compatibility profile): one display
list per unit primitive, one `glLoadMatrix` / `glColor` / `glCallList` per part, per-vertex
lighting with one directional light fixed to the camera and an ambient term.
"""

from __future__ import annotations

import os

# PyOpenGL picks its platform at first import: it must be OSMesa (no display needed).
os.environ["PYOPENGL_PLATFORM"] = "osmesa"

import numpy as np  # noqa: E402
from OpenGL import GL, osmesa  # noqa: E402

from vrsim_cli.maths.camera import Camera  # noqa: E402
from vrsim_cli.model.animation import appearance  # noqa: E402
from vrsim_cli.render.label import draw_label  # noqa: E402
from vrsim_cli.render.geometry import (PRIMITIVES, Stage, body_transforms, draw_list,  # noqa: E402
                                       sized_planes, spring_segments)

BACKGROUND = (0.92, 0.93, 0.95)  # RGB in [0, 1], the clear colour
GRID_COLOR = (0.62, 0.64, 0.68)
SPRING_COLOR = (0.15, 0.15, 0.18)
SPRING_WIDTH = 2.0  # px
ANCHOR_PX = 7.0  # px, the square dot at a spring's world anchor
TRAIL_WIDTH = 2.0  # px
TRAIL_SHADE = 0.6  # a trail is its body's colour times this (darker, on any ground)
LIGHT_DIR_EYE = (0.35, 0.6, 1.0, 0.0)  # towards the light, camera frame (w = 0: directional)
AMBIENT = 0.3
DIFFUSE = 0.75


class OsmesaUnavailable(Exception):
    """OSMesa could not give a context (library missing or too old)."""


class OsmesaRenderer:
    """Renders a model's bodies to (height, width, 3) uint8 RGB images.

    One OSMesa context per renderer; `close()` frees it.
    """

    def __init__(self, model, width: int, height: int, camera: Camera):
        self.width, self.height = int(width), int(height)
        self.camera = camera
        self.model = model
        self.context = osmesa.OSMesaCreateContextExt(osmesa.OSMESA_RGBA, 24, 0, 0, None)
        if not self.context:
            raise OsmesaUnavailable("OSMesaCreateContextExt returned no context")
        self.buffer = np.zeros((self.height, self.width, 4), dtype=np.uint8)
        self._make_current()
        self.parts = draw_list(model)
        self.opaque = self.parts.part_color[:, 3] >= 1.0
        # until set_stage: the old 20 m ground, or a flat grid behind a 2D scene
        self.stage = Stage(plane="xy", level=-0.01) if model.dimension == 2 else Stage()
        self.local = sized_planes(self.parts, self.stage)
        self.lists = self._compile_lists()
        self.part_list = np.array([self.lists[m] for m in self.parts.part_mesh], dtype=np.int64)
        self._setup()

    # ------------------------------------------------------------------ set-up

    def _make_current(self) -> None:
        """Bind this renderer's context and buffer (several renderers may coexist)."""
        if not osmesa.OSMesaMakeCurrent(self.context, self.buffer, GL.GL_UNSIGNED_BYTE,
                                        self.width, self.height):
            raise OsmesaUnavailable("OSMesaMakeCurrent failed")

    def _compile_lists(self) -> dict:
        lists = {}
        for name in dict.fromkeys(self.parts.part_mesh):
            if name in PRIMITIVES:
                lists[name] = _display_list(*PRIMITIVES[name](), closed=True)
            elif name in self.parts.meshes:  # a particle body's hull: flat in 2D, both sides
                lists[name] = _display_list(*self.parts.meshes[name], closed=False)
            else:  # a mesh file need not be closed or consistently wound: draw both sides
                lists[name] = _display_list(*_load_mesh(name), closed=False)
        self.grid_list = _grid_list(self.stage)
        return lists

    def set_stage(self, stage: Stage) -> None:
        """Draw the ground grid and the squares of planes sized to `stage` (the action of
        the run: `render.stage_for`) from the next image on."""
        self._make_current()
        GL.glDeleteLists(self.grid_list, 1)
        self.grid_list = _grid_list(stage)
        self.stage = stage
        self.local = sized_planes(self.parts, stage)

    def _setup(self) -> None:
        GL.glViewport(0, 0, self.width, self.height)
        GL.glClearColor(*BACKGROUND, 1.0)
        GL.glEnable(GL.GL_DEPTH_TEST)
        GL.glDepthFunc(GL.GL_LEQUAL)
        GL.glEnable(GL.GL_NORMALIZE)
        # The primitives are closed and wound counter-clockwise seen from outside: culling
        # back faces keeps them out of translucent blending and of tiny spheres' pixels.
        GL.glEnable(GL.GL_CULL_FACE)
        GL.glLightModeli(GL.GL_LIGHT_MODEL_TWO_SIDE, GL.GL_TRUE)  # for open meshes
        GL.glShadeModel(GL.GL_SMOOTH)
        # Filled geometry a little behind lines, so the grid shows on a ground plane.
        GL.glEnable(GL.GL_POLYGON_OFFSET_FILL)
        GL.glPolygonOffset(1.0, 1.0)
        GL.glBlendFunc(GL.GL_SRC_ALPHA, GL.GL_ONE_MINUS_SRC_ALPHA)
        GL.glLightModelfv(GL.GL_LIGHT_MODEL_AMBIENT, (0.0, 0.0, 0.0, 1.0))
        GL.glLightfv(GL.GL_LIGHT0, GL.GL_AMBIENT, (AMBIENT, AMBIENT, AMBIENT, 1.0))
        GL.glLightfv(GL.GL_LIGHT0, GL.GL_DIFFUSE, (DIFFUSE, DIFFUSE, DIFFUSE, 1.0))
        GL.glLightfv(GL.GL_LIGHT0, GL.GL_SPECULAR, (0.0, 0.0, 0.0, 1.0))
        GL.glEnable(GL.GL_LIGHT0)
        GL.glColorMaterial(GL.GL_FRONT_AND_BACK, GL.GL_AMBIENT_AND_DIFFUSE)
        GL.glEnable(GL.GL_COLOR_MATERIAL)
        self._use_camera(self.camera)

    def _use_camera(self, camera: Camera) -> None:
        GL.glMatrixMode(GL.GL_PROJECTION)
        GL.glLoadMatrixd(camera.projection_matrix(self.width / self.height).T)
        GL.glMatrixMode(GL.GL_MODELVIEW)
        GL.glLoadIdentity()  # the light is given in the camera frame: it moves with it
        GL.glLightfv(GL.GL_LIGHT0, GL.GL_POSITION, LIGHT_DIR_EYE)
        self.view = camera.view_matrix()
        self.current = camera

    # ------------------------------------------------------------------ drawing

    def render(self, state, overlay: str | None = None, camera: Camera | None = None,
               trails=()) -> np.ndarray:
        """The image of `state`: (height, width, 3) uint8, row 0 at the top.

        `camera` (e.g. the observer's, which moves) replaces the renderer's camera from
        this image on; None keeps the current one. `trails`: [(points (m, 3) m, RGB)],
        lines drawn through the points (the path a body has come along)."""
        self._make_current()
        if camera is not None and camera != self.current:
            self._use_camera(camera)
        GL.glClear(GL.GL_COLOR_BUFFER_BIT | GL.GL_DEPTH_BUFFER_BIT)
        GL.glDisable(GL.GL_LIGHTING)
        GL.glLoadMatrixd(self.view.T)
        GL.glColor3d(*GRID_COLOR)
        GL.glCallList(self.grid_list)
        GL.glEnable(GL.GL_LIGHTING)

        parts = self.parts
        world = body_transforms(state.body_pos, state.body_quat)
        colors = parts.part_color
        if self.model.animation is not None:  # keyframed colours and scales at this time
            looks = appearance(self.model.animation, state.t)
            if looks:
                colors = colors.copy()
                for body, look in looks.items():
                    if "color" in look:
                        colors[parts.part_body == body, :len(look["color"])] = look["color"]
                    if "scale" in look:
                        world[body] = world[body] @ np.diag([*look["scale"], 1.0])
        placed = np.where((parts.part_body >= 0)[:, None, None],
                          world[np.maximum(parts.part_body, 0)] @ self.local, self.local)
        modelview = self.view @ placed
        # Particles are drawn from their emission on; before that they wait out of sight.
        shown = self.model.body_emit_step[np.maximum(parts.part_body, 0)] <= state.step
        shown |= parts.part_body < 0
        # Opaque parts first, then translucent ones back to front (depth is -z in the eye).
        opaque = np.flatnonzero(shown & self.opaque)
        translucent = np.flatnonzero(shown & ~self.opaque)
        translucent = translucent[np.argsort(modelview[translucent, 2, 3])]
        self._draw(opaque, modelview, colors)
        self._lines(state, trails)
        if len(translucent):
            GL.glEnable(GL.GL_BLEND)
            GL.glDepthMask(GL.GL_FALSE)
            self._draw(translucent, modelview, colors)
            GL.glDepthMask(GL.GL_TRUE)
            GL.glDisable(GL.GL_BLEND)
        GL.glFinish()
        image = np.ascontiguousarray(self.buffer[::-1, :, :3])  # OSMesa's row 0 is the bottom
        if overlay:
            scale = max(1, self.height // 240)
            image = draw_label(image, overlay, 4 * scale, 4 * scale, scale)
        return image

    def _lines(self, state, trails) -> None:
        """Springs (between their two ends) and trails, unlit, over the opaque bodies."""
        springs = spring_segments(self.model, state)
        if not len(springs) and not len(trails):
            return
        GL.glDisable(GL.GL_LIGHTING)
        GL.glLoadMatrixd(self.view.T)
        if len(springs):
            GL.glLineWidth(SPRING_WIDTH)
            GL.glColor3d(*SPRING_COLOR)
            GL.glBegin(GL.GL_LINES)
            for a, b in springs:
                GL.glVertex3d(*a)
                GL.glVertex3d(*b)
            GL.glEnd()
            anchors = np.asarray(self.model.rigid.spring_b) < 0
            if anchors.any():  # where a spring holds in the world: a square dot
                GL.glPointSize(ANCHOR_PX)
                GL.glBegin(GL.GL_POINTS)
                for b in springs[anchors, 1]:
                    GL.glVertex3d(*b)
                GL.glEnd()
                GL.glPointSize(1.0)
        GL.glLineWidth(TRAIL_WIDTH)
        for points, color in trails:
            if len(points) < 2:
                continue
            GL.glColor3d(*(TRAIL_SHADE * np.asarray(color[:3], dtype=float)))
            GL.glBegin(GL.GL_LINE_STRIP)
            for p in points:
                GL.glVertex3d(*p)
            GL.glEnd()
        GL.glLineWidth(1.0)
        GL.glEnable(GL.GL_LIGHTING)

    def _draw(self, parts: np.ndarray, modelview: np.ndarray, colors: np.ndarray) -> None:
        # Column-major for OpenGL: the transpose, made contiguous once for all parts.
        matrices = np.ascontiguousarray(modelview.transpose(0, 2, 1))
        lists = self.part_list
        load, color, call = GL.glLoadMatrixd, GL.glColor4dv, GL.glCallList
        for i in parts:
            load(matrices[i])
            color(colors[i])
            call(int(lists[i]))

    def close(self) -> None:
        if self.context:
            osmesa.OSMesaDestroyContext(self.context)
            self.context = None


def _display_list(verts: np.ndarray, norms: np.ndarray, closed: bool) -> int:
    index = GL.glGenLists(1)
    GL.glNewList(index, GL.GL_COMPILE)
    if not closed:
        GL.glDisable(GL.GL_CULL_FACE)
    GL.glEnableClientState(GL.GL_VERTEX_ARRAY)
    GL.glEnableClientState(GL.GL_NORMAL_ARRAY)
    GL.glVertexPointer(3, GL.GL_FLOAT, 0, np.ascontiguousarray(verts, np.float32))
    GL.glNormalPointer(GL.GL_FLOAT, 0, np.ascontiguousarray(norms, np.float32))
    GL.glDrawArrays(GL.GL_TRIANGLES, 0, len(verts))
    GL.glDisableClientState(GL.GL_NORMAL_ARRAY)
    GL.glDisableClientState(GL.GL_VERTEX_ARRAY)
    if not closed:
        GL.glEnable(GL.GL_CULL_FACE)
    GL.glEndList()
    return index


def _grid_list(stage: Stage) -> int:
    index = GL.glGenLists(1)
    GL.glNewList(index, GL.GL_COMPILE)
    GL.glBegin(GL.GL_LINES)
    for a, b in stage.grid_lines():
        GL.glVertex3d(*a)
        GL.glVertex3d(*b)
    GL.glEnd()
    GL.glEndList()
    return index


def _load_mesh(path: str) -> tuple[np.ndarray, np.ndarray]:
    """Triangles of a mesh file with flat face normals (trimesh, imported only here)."""
    import trimesh

    mesh = trimesh.load(path, force="mesh")
    verts = np.asarray(mesh.vertices)[np.asarray(mesh.faces)].reshape(-1, 3)
    norms = np.repeat(np.asarray(mesh.face_normals), 3, axis=0)
    return verts.astype(np.float32), norms.astype(np.float32)
