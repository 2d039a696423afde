"""`tracker:=desktop`: the desktop (keyboard and mouse) tracker under its short name (see desktop_tracker)."""
from touch4d.nodes.desktop_tracker import DesktopTracker

NODE = DesktopTracker
