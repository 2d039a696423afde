"""`python -m touch4d.bus NODE [--name N] [--params JSON]`: one node process (what the launcher runs)."""
import sys

from touch4d.bus.process import main

sys.exit(main())
