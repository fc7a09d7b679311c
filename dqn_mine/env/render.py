"""Offscreen first-person rendering with moderngl through headless EGL.

One GL context per process, created lazily on the first render and shared by every environment of
that process (an actor may own several). Each environment owns one vertex buffer: the static
part (walls, floor, ceiling, door frames) is written once per reset and the entity part only when
an entity moves (pick up, drop, exchange), so a step uploads nothing but one uniform and issues
one draw call (two while an item is carried). The camera transform is done in the vertex shader
from (x, z, cos, sin), so no matrices are built in Python.
"""

from __future__ import annotations

import math
import os

import numpy as np

from dqn_mine.env.mesh import VERTEX_FLOATS, VERTEX_FORMAT

# llvmpipe rasterises on LP_NUM_THREADS extra threads. At 76x44 the hand-off costs more than the
# rasterisation it spreads, and with several actor processes per core the extra threads only fight
# each other: rendering in the calling thread (0) was fastest for 1 and 2 processes (see
# dqn_mine/bench/env.py and docs/benchmarks.md). Users can still override it.
DEFAULT_LP_NUM_THREADS = "0"

_VERTEX_SHADER = """
#version 330
uniform vec4 cam;    // eye x, eye z, cos(heading), sin(heading)
uniform vec4 proj;   // x scale, y scale, depth A, depth B
uniform float eye_y;
uniform vec2 tilt;   // cos, sin of the camera's downward pitch
uniform float on_top;   // 1 while the carried item is drawn over the world (see Scene.render)
in vec3 in_pos;
in vec3 in_col;
in float in_mat;
out vec3 v_col;
out vec3 v_pos;
out float v_mat;
out float v_depth;
void main() {
    vec3 p = in_pos - vec3(cam.x, eye_y, cam.y);
    float xv = -cam.w * p.x + cam.z * p.z;       // to the right of the heading
    float zl = -(cam.z * p.x + cam.w * p.z);     // negative in front of a level camera
    float yv = tilt.x * p.y - tilt.y * zl;       // pitched down about the view's x axis
    float zv = tilt.y * p.y + tilt.x * zl;
    // y is negated so that glReadPixels' first row is the top of the image.
    gl_Position = vec4(xv * proj.x, -yv * proj.y, proj.z * zv + proj.w, -zv);
    // Over the world: depth squeezed into the nearest 1% (NDC -1..-0.98), which nothing in the
    // world reaches (a wall 0.4 units ahead lies at about +0.75); the item's own faces still sort.
    if (on_top > 0.5) gl_Position.z = 0.01 * gl_Position.z - 0.99 * gl_Position.w;
    v_col = in_col;
    v_pos = in_pos;
    v_mat = in_mat;
    v_depth = -zv;
}
"""

_FRAGMENT_SHADER = """
#version 330
in vec3 v_col;
in vec3 v_pos;
in float v_mat;
in float v_depth;
out vec4 f_col;
float hash(vec3 p) {  // cheap value hash (no sin), enough for a rocky grain
    p = fract(p * 0.3183099 + 0.1) * 17.0;
    return fract(p.x * p.y * p.z * (p.x + p.y + p.z));
}
void main() {
    float t = 1.0;
    if (v_mat > 0.5 && v_mat < 1.5) {          // rock: coarse blotches + fine grain
        t = 0.72 + 0.22 * hash(floor(v_pos * vec3(1.3, 2.1, 1.3)))
                 + 0.10 * hash(floor(v_pos * 5.0));
    } else if (v_mat < 2.5 && v_mat > 1.5) {   // floor: gravel
        t = 0.80 + 0.25 * hash(floor(v_pos * 3.0));
    } else if (v_mat < 3.5 && v_mat > 2.5) {   // ceiling
        t = 0.80 + 0.20 * hash(floor(v_pos * 1.5));
    } else if (v_mat > 3.5) {                  // timber grain
        t = 0.85 + 0.15 * hash(floor(v_pos * vec3(9.0, 0.7, 9.0)));
    }
    // The robot's lamp: light falls off with distance, like a headlamp in a dark mine.
    float lamp = 1.0 / (1.0 + 0.0012 * v_depth * v_depth);
    f_col = vec4(v_col * t * lamp, 1.0);
}
"""


class _Gl:
    """The per-process GL objects: context, program and the observation framebuffer."""

    def __init__(self, width: int, height: int):
        os.environ.setdefault("LP_NUM_THREADS", DEFAULT_LP_NUM_THREADS)
        import moderngl

        try:
            self.ctx = moderngl.create_context(standalone=True, backend="egl")
        except Exception as exc:  # moderngl/glcontext raise plain Exceptions here
            detail = " ".join(str(exc).split())
            raise RuntimeError(
                "cannot initialise headless EGL for rendering: install libEGL with Mesa (llvmpipe, "
                f"e.g. apt-get install libegl1 libgl1-mesa-dri) or the NVIDIA driver ({detail})"
            ) from None
        self.pid = os.getpid()
        self.size = (width, height)
        self.prog = self.ctx.program(vertex_shader=_VERTEX_SHADER, fragment_shader=_FRAGMENT_SHADER)
        self.fbo = self.ctx.framebuffer(self.ctx.renderbuffer((width, height)),
                                        self.ctx.depth_renderbuffer((width, height)))
        self.cam = self.prog["cam"]
        self.proj = self.prog["proj"]
        self.eye_y = self.prog["eye_y"]
        self.tilt = self.prog["tilt"]
        self.on_top = self.prog["on_top"]
        self.on_top.value = 0.0
        self.pixels = np.empty((height, width, 3), np.uint8)
        self.ctx.enable(self.ctx.DEPTH_TEST)
        self.fbo.use()
        self.projection = None


_GL: _Gl | None = None


def gl(width: int, height: int) -> _Gl:
    """The process's GL objects, created on first use (and again in a forked child)."""
    global _GL
    if _GL is None or _GL.pid != os.getpid():
        _GL = _Gl(width, height)
    if _GL.size != (width, height):
        raise ValueError(f"one process renders one observation size; got {width}x{height} after "
                         f"{_GL.size[0]}x{_GL.size[1]}")
    return _GL


class Scene:
    """One environment's vertex buffer, drawn from the agent's eye into a (3, H, W) image."""

    def __init__(self, width: int, height: int, fov_y: float, eye_height: float, far: float,
                 pitch: float = 0.0, held_on_top: bool = False):
        self.g = gl(width, height)
        self.held_on_top = held_on_top
        self.aspect, self.far = height / width, far
        self.fov_y = None
        self.set_fov(fov_y)
        self.eye_height = float(eye_height)
        self.tilt = (math.cos(math.radians(pitch)), math.sin(math.radians(pitch)))
        self.capacity = 0
        self.vbo = None
        self.vao = None
        self.static_n = 0
        self.count = 0
        self.held_n = 0

    def set_fov(self, fov_y: float) -> None:
        """Vertical field of view in degrees (a new projection tuple, so render() uploads it)."""
        if fov_y == self.fov_y:
            return
        self.fov_y = fov_y
        f = 1.0 / math.tan(math.radians(fov_y) / 2)
        near, far = 0.05, self.far
        self.projection = (f * self.aspect, f,
                           (far + near) / (near - far), 2 * far * near / (near - far))

    def set_static(self, static: np.ndarray, dynamic: np.ndarray,
                   held: np.ndarray | None = None) -> None:
        """Upload a new scene (at reset): static geometry followed by the entities."""
        self.static_n = len(static)
        # Room for the entities to grow (a dropped item reappears) without reallocating.
        need = (len(static) + len(dynamic) + 2048) * VERTEX_FLOATS * 4
        if need > self.capacity:
            self.release()
            self.capacity = max(need, 2 * self.capacity)
            ctx = self.g.ctx
            self.vbo = ctx.buffer(reserve=self.capacity)
            self.vao = ctx.vertex_array(
                self.g.prog, [(self.vbo, VERTEX_FORMAT, "in_pos", "in_col", "in_mat")])
        self.vbo.write(static)
        self.set_dynamic(dynamic, held)

    def set_dynamic(self, dynamic: np.ndarray, held: np.ndarray | None = None) -> None:
        """Rewrite the entity part of the buffer (after an entity moved).

        ``held`` is the carried item in the camera's own frame (eye at x = z = 0 looking along +x),
        drawn after the world from that fixed frame: it stays in front of the agent without a
        buffer upload per step. The shared depth buffer lets a near wall or a faced item hide it,
        unless the scene draws it on top (``held_on_top``).
        """
        offset = self.static_n * VERTEX_FLOATS * 4
        held = held if held is not None else dynamic[:0]
        if offset + dynamic.nbytes + held.nbytes > self.capacity:
            raise RuntimeError("entity geometry outgrew its vertex buffer")
        if len(dynamic) or len(held):
            self.vbo.write(np.concatenate([dynamic, held]), offset=offset)
        self.count = self.static_n + len(dynamic)
        self.held_n = len(held)

    def render(self, x: float, z: float, cos: float, sin: float) -> np.ndarray:
        """The first-person image from (x, z) looking along (cos, sin): uint8 (3, H, W)."""
        g = self.g
        if g.projection is not self.projection:  # envs of one process may differ in fov/eye
            g.proj.value = self.projection
            g.eye_y.value = self.eye_height
            g.tilt.value = self.tilt
            g.projection = self.projection
        g.cam.value = (x, z, cos, sin)
        g.fbo.clear(0.0, 0.0, 0.0, 1.0)
        self.vao.render(vertices=self.count)
        if self.held_n:
            g.cam.value = (0.0, 0.0, 1.0, 0.0)
            if self.held_on_top:
                g.on_top.value = 1.0
            self.vao.render(vertices=self.held_n, first=self.count)
            if self.held_on_top:   # the program is shared: the next scene draws the world
                g.on_top.value = 0.0
        g.fbo.read_into(g.pixels, components=3)
        return g.pixels.transpose(2, 0, 1).copy()

    def release(self) -> None:
        for obj in (self.vao, self.vbo):
            if obj is not None:
                obj.release()
        self.vao = self.vbo = None
        self.capacity = 0
