"""`tracker:=desktop`: the desktop (keyboard and mouse) tracker under its short name (see desktop_tracker)."""
from touch4d.nodes.desktop_tracker import DesktopTracker, main

__all__ = ["DesktopTracker", "main"]

if __name__ == "__main__":
    raise SystemExit(main())
