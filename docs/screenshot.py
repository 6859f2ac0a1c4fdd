"""Screenshot of a saved Rerun recording, headless (software Vulkan), for the README.

Run:  vmp map office --rerun office.rrd
      python docs/screenshot.py office.rrd docs/rerun_office.png

Needs Debian's software Vulkan driver (`apt-get install mesa-vulkan-drivers`). The viewer
runs headless on a spare port; the script opens the recording in it, gives it time to load
and draw (software rendering is slow), and asks it for a screenshot.
"""

from __future__ import annotations

import argparse
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("recording", type=Path)
    ap.add_argument("png", type=Path)
    ap.add_argument("--size", default="1600x900", help="window size in points")
    ap.add_argument("--port", type=int, default=9877)
    ap.add_argument("--wait", type=float, default=8.0, help="seconds to let it load and draw")
    args = ap.parse_args()
    from rerun.experimental import ViewerClient

    rerun = shutil.which("rerun") or str(Path(sys.executable).parent / "rerun")
    viewer = subprocess.Popen(
        [rerun, "--headless", "--renderer", "vulkan", "--window-size", args.size,
         "--port", str(args.port), "--hide-welcome-screen"],
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
        start_new_session=True)  # its own process group: the wrapper starts the binary
    try:
        client = None
        for _ in range(100):
            try:
                client = ViewerClient.connect(f"rerun+http://127.0.0.1:{args.port}/proxy")
                break
            except Exception:  # not listening yet
                time.sleep(0.2)
        if client is None:
            print("the headless viewer did not start", file=sys.stderr)
            return 1
        client.open(str(args.recording.resolve()))
        time.sleep(args.wait)
        args.png.parent.mkdir(parents=True, exist_ok=True)
        client.save_screenshot(str(args.png.resolve()))
        print(f"screenshot: {args.png}")
        return 0
    finally:
        os.killpg(viewer.pid, signal.SIGTERM)
        viewer.wait(timeout=10)


if __name__ == "__main__":
    raise SystemExit(main())
