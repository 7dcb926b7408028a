"""Child process for the crash tests: records scans forever (up to a cap), printing the
sequence number of each scan once ``write_scan`` has returned, until it is killed."""

from __future__ import annotations

import sys

from lasercal_hw.session.recorder import SessionRecorder
from tests.recorder_helpers import START_TIME_S, make_pose, make_scan

MAX_SCANS = 20_000


def main(path: str) -> None:
    recorder = SessionRecorder(path, {"child": True})
    print("ready", flush=True)
    for i in range(MAX_SCANS):
        recorder.write_scan(make_scan(i))
        if i % 10 == 0:
            recorder.write_tcp_pose(START_TIME_S + i * 0.025, make_pose(i))
            recorder.write_event(START_TIME_S + i * 0.025, "dwell_start", index=i)
        try:
            print(i, flush=True)
        except BrokenPipeError:  # the test went away: stop
            return
    recorder.close()


if __name__ == "__main__":
    main(sys.argv[1])
