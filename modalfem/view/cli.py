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
    stop = threading.Event()
    previous = None
    if threading.current_thread() is threading.main_thread():
        previous = signal.signal(signal.SIGTERM, lambda *_: stop.set())
    try:
        explorer.start()
        print(f"modalfem view: {explorer.url} ({model.mode_count} modes, {model.vertex_count} vertices; "
              f"Ctrl-C to stop)", flush=True)
        if not args.no_browser:
            import webbrowser

            webbrowser.open(explorer.url)
        try:
            while not stop.wait(0.2):
                pass
        except KeyboardInterrupt:
            pass
    finally:
        explorer.close()
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)
    print("modalfem view: stopped", flush=True)
    return 0
