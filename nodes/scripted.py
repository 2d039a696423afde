"""`tracker:=scripted`: the scripted tracker under its short name (see scripted_tracker)."""
from touch4d.nodes.scripted_tracker import ScriptedTracker

NODE = ScriptedTracker
