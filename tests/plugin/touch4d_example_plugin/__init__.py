"""An example package with a touch4d node (see touch4d's docs/nodes.md)."""
