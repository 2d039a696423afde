"""Topic logs: record the bus into MCAP files, replay them with their timing, inspect and export them.

- `writer.LogWriter` / `reader.LogReader`: the file layer (original msgpack bytes, receive time as
  log_time, `stamp` as publish_time, `seq` as sequence; one JSON schema per message type).
- `recorder.Recorder`: a bus subscriber thread + a writer thread; crash-safe every 0.5 s.
- `replay.Replayer`: republishes with the recorded timing, streaming the file; re-stamped as it goes
  out (`restamp`: the bytes patched, the recorded stamp kept in `recorded_stamp`) unless asked not to.
- `summary`, `export`, `recover`: `touch4d log info|export|recover`.
"""
