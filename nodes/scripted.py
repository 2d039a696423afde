"""`tracker:=scripted`: the scripted tracker under its short name (see scripted_tracker)."""
from touch4d.nodes.scripted_tracker import ScriptedTracker, main

__all__ = ["ScriptedTracker", "main"]

if __name__ == "__main__":
    raise SystemExit(main())
