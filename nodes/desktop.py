"""`tracker:=desktop`: the desktop (keyboard and mouse) tracker under its short name (see desktop_tracker)."""
from touch4d.nodes.desktop_tracker import DesktopTracker

NODE = DesktopTracker


if __name__ == "__main__":   # python -m touch4d.nodes.NAME: run it, as `touch4d node run NAME` does
    from touch4d.bus.process import main_for_module

    main_for_module(__spec__.name)
