"""The WebXR page and its server: the 4D scene in a headset's (or a desktop) browser, the headset as tracker.

protocol      the WebSocket frames between node and page (binary frames out, checked JSON in)
bridge        topics <-> pages without I/O: what pages get, what they publish, the fail-safe
scene_frames  the scene as the page draws it: geometry once, per frame only transforms
server        aiohttp in a thread: the page, its files and one WebSocket per page
access        who may open the page: tokens per holder, the cookie they are exchanged for, the link
tls           https beyond loopback: the self-signed certificate, its key written safely
static/       the page itself: ES modules, WebGL2 and WebXR, no build step, no dependency
"""
