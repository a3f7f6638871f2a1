"""The process' pyrender offscreen renderer (EGL) and its silhouette-union mode.

- One EGL context per process, shared by every :class:`~opnet.synthesis.rendering.SceneRenderer`
  and resized as needed: pyrender's ``OffscreenRenderer.delete()`` terminates the EGL display,
  which breaks every other context of the process, so the shared renderer is never deleted.
- Union mode counts the silhouettes of up to 24 objects in one pass: depth test off, colour
  logic op OR, object j drawn in the colour with only bit j set (bits 0-7 red, 8-15 green, 16-23
  blue). Every pixel then holds the set of objects whose silhouette covers it, whatever hides
  what. pyrender has no switch for this, so the renderer's viewport set-up (the private
  ``Renderer._configure_forward_pass_viewport`` of the pinned pyrender 0.1.45) is wrapped to add
  the two GL state changes; the SEG pass already disables multisampling and draws flat colours,
  so all samples of a pixel agree and the resolve keeps the bits exact.
- Only SEG passes are drawn here (multisampling off), so the renderer's framebuffer is made
  single-sample (its private ``_configure_main_framebuffer`` is wrapped likewise): the same pixels,
  about 25 % less rendering time in llvmpipe. Other pyrender renderers of the process keep theirs.
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator

import numpy as np

os.environ.setdefault("PYOPENGL_PLATFORM", "egl")
if not hasattr(np, "infty"):
    np.infty = np.inf  # pyrender 0.1.45 still uses the name numpy 2 removed

import pyrender  # noqa: E402
import pyrender.renderer  # noqa: E402
from OpenGL.GL import (  # noqa: E402
    GL_COLOR_BUFFER_BIT,
    GL_COLOR_LOGIC_OP,
    GL_DEPTH_TEST,
    GL_DRAW_FRAMEBUFFER,
    GL_NEAREST,
    GL_OR,
    GL_READ_FRAMEBUFFER,
    GL_RGB,
    GL_UNSIGNED_BYTE,
    glBindFramebuffer,
    glBlitFramebuffer,
    glDisable,
    glEnable,
    glLogicOp,
    glReadPixels,
)

#: objects per union pass (bits of an RGB8 pixel)
UNION_BITS = 24

_SHARED: pyrender.OffscreenRenderer | None = None
_UNION = {"on": False}


def shared_renderer(width: int, height: int) -> pyrender.OffscreenRenderer:
    """The process' offscreen renderer, set to ``width`` x ``height`` pixels."""
    global _SHARED
    if _SHARED is None:
        _SHARED = pyrender.OffscreenRenderer(width, height)
        _wrap_viewport_setup(_SHARED)
    _SHARED.viewport_width, _SHARED.viewport_height = width, height
    return _SHARED


def _wrap_viewport_setup(renderer: pyrender.OffscreenRenderer) -> None:
    inner = renderer._renderer
    original = inner._configure_forward_pass_viewport
    make_framebuffer = inner._configure_main_framebuffer

    def single_sample_framebuffer() -> None:
        # the SEG pass draws with multisampling off: 4 identical samples per pixel only cost time
        module = pyrender.renderer
        storage = module.glRenderbufferStorageMultisample
        module.glRenderbufferStorageMultisample = lambda target, _samples, fmt, w, h: storage(target, 0, fmt, w, h)
        try:
            make_framebuffer()
        finally:
            module.glRenderbufferStorageMultisample = storage

    def configure(flags: int) -> None:
        original(flags)
        if _UNION["on"]:
            glDisable(GL_DEPTH_TEST)
            glEnable(GL_COLOR_LOGIC_OP)
            glLogicOp(GL_OR)
        else:
            glDisable(GL_COLOR_LOGIC_OP)

    read_both = inner._read_main_framebuffer

    def read(scene: pyrender.Scene, flags: int) -> tuple[np.ndarray, np.ndarray | None]:
        # a union pass needs the colour bits only: skip pyrender's depth read-back and its
        # linearization (the union canvas may be several images large)
        if not _UNION["on"]:
            return read_both(scene, flags)
        width, height = inner._main_fb_dims
        glBindFramebuffer(GL_READ_FRAMEBUFFER, inner._main_fb_ms)
        glBindFramebuffer(GL_DRAW_FRAMEBUFFER, inner._main_fb)
        glBlitFramebuffer(0, 0, width, height, 0, 0, width, height, GL_COLOR_BUFFER_BIT, GL_NEAREST)
        glBindFramebuffer(GL_READ_FRAMEBUFFER, inner._main_fb)
        buf = glReadPixels(0, 0, width, height, GL_RGB, GL_UNSIGNED_BYTE)
        return np.flip(np.frombuffer(buf, dtype=np.uint8).reshape(height, width, 3), axis=0), None

    inner._configure_forward_pass_viewport = configure
    inner._configure_main_framebuffer = single_sample_framebuffer
    inner._read_main_framebuffer = read


@contextlib.contextmanager
def union_mode() -> Iterator[None]:
    """Within the block, SEG renders OR the objects' colours together, without depth test."""
    _UNION["on"] = True
    try:
        yield
    finally:
        _UNION["on"] = False


def bit_color(j: int) -> tuple[int, int, int]:
    """The RGB colour with only bit ``j`` (0 .. 23) set."""
    if not 0 <= j < UNION_BITS:
        raise ValueError(f"bit {j} outside 0..{UNION_BITS - 1}")
    rgb = [0, 0, 0]
    rgb[j // 8] = 1 << (j % 8)
    return rgb[0], rgb[1], rgb[2]


def count_bits(color: np.ndarray, n: int) -> np.ndarray:
    """(n,) int64 pixels of an (H, W, 3) uint8 union image that have bit j set, j = 0 .. n - 1."""
    c = color.astype(np.uint32)
    v = c[..., 0] | (c[..., 1] << 8) | (c[..., 2] << 16)
    v = v[v != 0]
    return np.array([np.count_nonzero(v & np.uint32(1 << j)) for j in range(n)], dtype=np.int64)
