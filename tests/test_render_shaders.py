"""One shader source for two platforms: every shader compiles and links as desktop GLSL 3.30 and as
GLSL ES 3.00 (WebGL2's language; Mesa's compiler applies the ES rules to `#version 300 es`)."""
from __future__ import annotations

import moderngl
import pytest

from touch4d.render.context import create_headless_context
from touch4d.render.glsl import shader_names, shader_source

# Every program the backends link: (vertex, fragment).
PROGRAMS = [("scene_face.vert", "scene.frag"), ("scene_centre.vert", "scene.frag"), ("scene_edge.vert", "scene.frag"),
            ("fullscreen.vert", "bounds.frag"), ("fullscreen.vert", "view.frag"), ("fullscreen.vert", "grid.frag"),
            ("fullscreen.vert", "oit.frag"), ("fullscreen.vert", "tactile.frag"),
            ("flat.vert", "flat.frag"), ("flat.vert", "flat_oit.frag"), ("flat.vert", "id.frag"), ("line.vert", "flat.frag"),
            ("line.vert", "id.frag"),
            ("point.vert", "point.frag"), ("overlay.vert", "overlay.frag")]


@pytest.fixture(scope="module")
def ctx():
    context = create_headless_context()
    yield context
    context.release()


def test_every_shader_file_is_in_a_program():
    assert sorted({name for pair in PROGRAMS for name in pair}) == shader_names()


@pytest.mark.parametrize("profile", ["gl330", "es300"])
def test_every_program_links_in_both_profiles(ctx, profile):
    for vertex, fragment in PROGRAMS:
        vs, fs = shader_source(vertex, profile), shader_source(fragment, profile)
        first = {"gl330": "#version 330 core", "es300": "#version 300 es"}[profile]
        assert vs.splitlines()[0] == first and fs.splitlines()[0] == first
        assert "#include" not in vs + fs
        ctx.program(vertex_shader=vs, fragment_shader=fs).release()


def test_the_es_profile_really_applies_the_es_rules(ctx):
    """Desktop GLSL converts int to float implicitly; GLSL ES does not. The same body must build in one
    profile and fail in the other, or the ES check above would prove nothing."""
    body = "in vec4 p;\nout float v;\nvoid main() { int i = 2; v = 1.0 + i; gl_Position = p; }\n"
    fragment = "in float v;\nout vec4 c;\nvoid main() { c = vec4(v); }\n"
    from touch4d.render.glsl import PROFILES

    ctx.program(vertex_shader=PROFILES["gl330"] + body, fragment_shader=PROFILES["gl330"] + fragment).release()
    with pytest.raises(moderngl.Error):
        ctx.program(vertex_shader=PROFILES["es300"] + body, fragment_shader=PROFILES["es300"] + fragment)


def test_unknown_profile_and_shader_are_named():
    with pytest.raises(ValueError, match="es100"):
        shader_source("scene.frag", "es100")
    with pytest.raises(ValueError, match="nope.frag"):
        shader_source("nope.frag")

