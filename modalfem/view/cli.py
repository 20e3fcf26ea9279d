"""``modalfem view MODEL.npz``: serve a live mode explorer of a model file to the browser.

Prints the page's address on stdout, opens it in the default browser (unless ``--no-browser``) and
serves until Ctrl-C or SIGTERM, which stop it cleanly (exit 0). A bad model file, mode number or
busy port is one line ``modalfem: error: ...`` and exit code 2 (raised as ``ModalfemError`` to
``modalfem.cli.main``).
"""

from __future__ import annotations

import argparse
import signal
import sys
import threading
import time

from modalfem.cli import _Parser  # usage errors: one line, exit code 2

__all__ = ["build_parser", "main"]


def build_parser() -> argparse.ArgumentParser:
    p = _Parser(prog="modalfem view", description="Live mode explorer of a model file in the browser: "
                "pick a mode, amplitude, animate; click the body to strike it and hear it.")
    p.add_argument("model", metavar="MODEL.npz", help="model file written by `modalfem modes ... --save`")
    p.add_argument("--port", type=int, default=0, help="TCP port (default 0: a free one; the URL is printed)")
    p.add_argument("--host", default="127.0.0.1", help="interface to listen on (default 127.0.0.1, this machine)")
    p.add_argument("--no-browser", action="store_true", help="do not open a browser; just print the URL")
    p.add_argument("--mode", type=int, default=1, help="mode shown first, 1 = lowest (default 1)")
    p.add_argument("--amplitude", type=float, default=0.05,
                   help="peak displacement shown, fraction of the body's size (default 0.05)")
    p.add_argument("--impulse", type=float, default=None, help="strike impulse [N s] (default: mass x 0.1 m/s)")
    return p


def main(argv: list[str] | None = None) -> int:
    """Run ``modalfem view``; returns the exit code (0 after Ctrl-C / SIGTERM)."""
    args = build_parser().parse_args(sys.argv[1:] if argv is None else argv)
    from modalfem.model import ModalModel
    from modalfem.view.explorer import ModeExplorer

    model = ModalModel.load(args.model)
    explorer = ModeExplorer(model, mode=args.mode, amplitude=args.amplitude, impulse=args.impulse,
                            host=args.host, port=args.port)
    stopping: list[int] = []  # a signal handler only appends: no lock taken there (Event.set in a handler can
    # deadlock when the signal lands while the main thread holds the event's own lock)
    previous = {}
    if threading.current_thread() is threading.main_thread():
        # Ctrl-C and SIGTERM only mark the stop: a KeyboardInterrupt raised at an arbitrary bytecode (inside a lock's
        # wait, say) could leave a lock held and the shutdown stuck
        for sig in (signal.SIGINT, signal.SIGTERM):
            previous[sig] = signal.signal(sig, lambda *_: stopping.append(1))
    try:
        explorer.start()
        print(f"modalfem view: {explorer.url} ({model.mode_count} modes, {model.vertex_count} vertices; "
              f"Ctrl-C to stop)", flush=True)
        if not args.no_browser:
            import webbrowser

            webbrowser.open(explorer.url)
        while not stopping:
            time.sleep(0.1)  # interrupted by a signal: its handler runs, then the loop sees the mark
    finally:
        explorer.close()
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    print("modalfem view: stopped", flush=True)
    return 0
