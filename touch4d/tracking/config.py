"""Constants of the tracking package's files and nodes (the files themselves are declared as Structs
beside the code that uses them: calibration.py, paths.py)."""
from __future__ import annotations

from touch4d import configfile

CONFIG_DIR = configfile.CONFIG_DIR
MAX_TRACKER_RATE = 1000.0   # Hz: the tracker role publishes at up to 1 kHz
