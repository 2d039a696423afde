"""`tracker:=scripted`: the scripted tracker under its short name (see scripted_tracker)."""
from touch4d.nodes.scripted_tracker import ScriptedTracker

NODE = ScriptedTracker


if __name__ == "__main__":   # python -m touch4d.nodes.NAME: run it, as `touch4d node run NAME` does
    from touch4d.bus.process import main_for_module

    main_for_module(__spec__.name)
