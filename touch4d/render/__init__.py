"""Drawing the 4D scene on the 3D screen (paper §4.3) with moderngl, shared by the renderer node and
`touch4d render`: `scene_mesh` builds a frame's vertex arrays on the CPU (culling, clip units, convex
pieces), `draw` paints them, `hud` adds the screen frame, hand, tactile cube and status line, `view`
keeps the last good inputs and renders offscreen, `window` is the interactive window."""
