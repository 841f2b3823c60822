"""Screenshot of the Rerun web viewer (manual check, not part of the test suite).

    .venv/bin/python docs/tools/rerun_screenshot.py out/run.rrd docs/figures/rerun_envelope.png
    .venv/bin/python docs/tools/rerun_screenshot.py --live docs/figures/rerun_live.png -- CMD ...

File mode serves the `.rrd` with `rerun --serve-web --bind 127.0.0.1`. Live mode starts an empty
`rerun --serve-web` viewer (its gRPC proxy on loopback), opens it in the browser, then runs CMD (after
`--`) with `{grpc}` in its arguments replaced by the proxy URL, e.g. the rig node with
`-p rerun:=connect:{grpc}`, so the data reaches the viewer while it is open. The shot is taken `--wait`
seconds after the page is opened (the wasm viewer needs ~20-40 s under SwiftShader) and downscaled to
at most `--max-width` pixels.

Needs Debian's chromium (`apt-get install chromium`) and playwright's Python package
(`.venv/bin/pip install playwright`; no browser download). Neither is a project dependency. Every
process started here (rerun and its child, chromium, CMD) is stopped before exit.
"""

from __future__ import annotations

import argparse
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

CHROMIUM = "/usr/bin/chromium"
CHROMIUM_ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                 "--disable-background-networking", "--disable-component-update", "--disable-sync"]


def _wait_port(port: int, timeout_s: float) -> None:
    import socket

    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        with socket.socket() as s:
            if s.connect_ex(("127.0.0.1", port)) == 0:
                return
        time.sleep(0.2)
    raise RuntimeError(f"nothing listens on 127.0.0.1:{port} after {timeout_s} s")


def _stop(proc: subprocess.Popen) -> None:
    """SIGINT then SIGKILL to the process group (`rerun` is a Python wrapper with a child)."""
    if proc.poll() is None:
        os.killpg(proc.pid, signal.SIGINT)
        try:
            proc.wait(10)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    try:
        os.killpg(proc.pid, signal.SIGKILL)  # leftovers in the group, if any
    except ProcessLookupError:
        pass


def _downscale(path: Path, max_width: int) -> None:
    from PIL import Image

    img = Image.open(path).convert("RGB")
    if img.width > max_width:
        img = img.resize((max_width, round(img.height * max_width / img.width)), Image.LANCZOS)
    img.save(path, optimize=True)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("source", nargs="?", help=".rrd file to serve (file mode)")
    ap.add_argument("png", help="screenshot to write")
    ap.add_argument("--live", action="store_true", help="serve an empty viewer and run CMD against it")
    ap.add_argument("--web-port", type=int, default=19090)
    ap.add_argument("--grpc-port", type=int, default=19876)
    ap.add_argument("--wait", type=float, default=40.0, help="seconds before the shot (after CMD ends, if any)")
    ap.add_argument("--size", default="1600x900", help="browser viewport WxH")
    ap.add_argument("--max-width", type=int, default=1280)
    argv = sys.argv[1:]
    cmd = argv[argv.index("--") + 1:] if "--" in argv else []
    args = ap.parse_args(argv[: argv.index("--")] if "--" in argv else argv)
    if args.live == (args.source is not None):
        ap.error("give a .rrd source, or --live (with CMD after --), not both")
    width, height = (int(v) for v in args.size.split("x"))
    rerun = str(Path(sys.executable).with_name("rerun"))
    grpc = f"rerun+http://127.0.0.1:{args.grpc_port}/proxy"
    serve = [rerun, "--serve-web", "--bind", "127.0.0.1", "--web-viewer-port", str(args.web_port),
             "--port", str(args.grpc_port)]
    serve += [] if args.live else [args.source]
    procs: list[subprocess.Popen] = []
    from playwright.sync_api import sync_playwright

    try:
        procs.append(subprocess.Popen(serve, start_new_session=True))
        _wait_port(args.web_port, 60)
        _wait_port(args.grpc_port, 60)
        url = f"http://127.0.0.1:{args.web_port}/?url={grpc}"
        with tempfile.TemporaryDirectory(prefix="rerun_shot_") as profile, sync_playwright() as pw:
            browser = pw.chromium.launch_persistent_context(
                profile, executable_path=CHROMIUM, headless=True, args=CHROMIUM_ARGS,
                viewport={"width": width, "height": height},
            )
            try:
                page = browser.new_page() if not browser.pages else browser.pages[0]
                page.goto(url)
                t_open = time.monotonic()
                if cmd:
                    cmd = [c.replace("{grpc}", grpc) for c in cmd]
                    print("running:", " ".join(cmd), flush=True)
                    run = subprocess.Popen(cmd, start_new_session=True)
                    procs.append(run)
                    run.wait()
                    print(f"command exit {run.returncode}", flush=True)
                time.sleep(args.wait if cmd else max(0.0, args.wait - (time.monotonic() - t_open)))
                page.screenshot(path=args.png)
            finally:
                browser.close()
    finally:
        for proc in reversed(procs):
            _stop(proc)
    _downscale(Path(args.png), args.max_width)
    print(f"{args.png}: {Path(args.png).stat().st_size // 1024} KB", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
