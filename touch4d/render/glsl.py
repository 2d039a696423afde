"""GLSL sources for two platforms from one set of files: desktop GLSL 3.30 (moderngl) and GLSL ES 3.00
(WebGL2, the WebXR page).

The files in `shaders/` are written in the common subset of the two and carry no `#version` line;
`shader_source` prepends the profile's version line (and, for ES, default precisions) and expands
`#include "file.glsl"` lines, each file once.
"""
from __future__ import annotations

import re
from functools import lru_cache
from importlib import resources

PROFILES = {
    "gl330": "#version 330 core\n",
    "es300": "#version 300 es\nprecision highp float;\nprecision highp int;\nprecision highp sampler2D;\n",
}
_INCLUDE = re.compile(r'^\s*#include\s+"([^"]+)"\s*$', re.MULTILINE)


def shader_source(name: str, profile: str = "gl330") -> str:
    """The full source of shader `name` (a file in shaders/ without its .glsl, e.g. "scene.frag") for
    `profile`, "gl330" or "es300"."""
    if profile not in PROFILES:
        raise ValueError(f"profile: expected one of {', '.join(PROFILES)}, got {profile!r}")
    return PROFILES[profile] + _expanded(f"{name}.glsl")


def shader_names() -> list[str]:
    """Every complete shader (vertex or fragment stage), as names `shader_source` takes."""
    files = resources.files("touch4d.render").joinpath("shaders").iterdir()
    return sorted(f.name[:-5] for f in files if f.name.endswith((".vert.glsl", ".frag.glsl")))


@lru_cache(maxsize=None)
def _expanded(file: str) -> str:
    seen: set[str] = set()

    def expand(name: str) -> str:
        if name in seen:
            return ""
        seen.add(name)
        try:
            text = resources.files("touch4d.render").joinpath("shaders", name).read_text()
        except FileNotFoundError:
            raise ValueError(f"shader file {name!r} not found in touch4d/render/shaders") from None
        return _INCLUDE.sub(lambda m: expand(m.group(1)), text)

    return expand(file)
