"""Drawing the 4D scene on the 3D screen (paper §4.2-4.3), shared by the renderer node and `touch4d render`.

`frame` is the GL-free frame model (the scene layer, the flat layers around it) and `scene_geometry`
the scene as plain arrays (geometry per revision, transforms per frame); `view` keeps the last good
inputs and makes frames. Backends draw frames with moderngl (`backends`): `gpu` projects in shaders
and removes hidden hypersurfaces per fragment by the tactile ray test; `clip` is the paper's clip-unit
build on the CPU (`clip`). `glsl` serves the shaders as desktop GLSL 3.30 or GLSL ES 3.00; `draw`
paints the flat layers, `hud` builds them (screen frame, hand, tactile cube, status line),
`offscreen` renders without a window, `window` is the interactive one.
"""
