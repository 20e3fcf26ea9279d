"""``modalfem bench view``: what a live-viewer frame costs when it carries q versus vertex positions.

A surface of nv vertices with r modes animates at 60 updates per second (every modal coordinate
changing) in headless Chromium (Debian's ``/usr/bin/chromium`` driven by Playwright, software
WebGL through SwiftShader: the page's drawing runs on the CPU, so the figures are lower bounds for a
machine with a GPU). Side by side in one run, per size:

* ``q``: ``Viewer`` frames carry the r modal coordinates; the page computes ``X + Phi q`` itself, in
  its vertex shader (modes in float textures; with SwiftShader that shader also runs on the CPU);
* ``positions``: the server computes ``X + Phi q`` (numpy) and frames carry the nv x 3 float32
  positions (base64 in the event stream), as a body without modes would;
* ``viser`` (the peer, when ``import viser`` works): the server computes the positions and sets
  ``mesh.vertices`` each update (viser's own websocket protocol and three.js page).

Measured over ``--seconds`` after a warm-up (1 s; 4 s for viser, whose page builds a React app):
page frames per second (requestAnimationFrame callbacks, all cases alike), frames the page received
per second (ours; a page that falls behind gets the newest frame only), the page's own time to apply
one (deform, normals, upload; ours), the server's time per update (computing and publishing) and the
bytes of one frame. The surface is a closed torus grid; mode shapes are random (the cost does not depend on them).
"""

from __future__ import annotations

import argparse
import datetime as _dt
import json
import os
import shlex
import socket
import sys
import threading
import time

import numpy as np

__all__ = ["SECTION", "command", "measure", "render"]

SECTION = "## View: per-frame transport of the live viewer"
VERTICES = (2_000, 10_000, 50_000)
MODES = 20
RATE = 60.0  # updates per second sent
CHROMIUM = os.environ.get("MODALFEM_CHROMIUM", "/usr/bin/chromium")
_COUNT_JS = """(s) => new Promise((done) => {
  const V = window.modalfemViewer || {};
  const r0 = V.framesReceived || 0, d0 = V.deforms || 0, m0 = V.deformMs || 0;
  let n = 0; const t0 = performance.now();
  function f() { n++; if (performance.now() - t0 < 1000 * s) requestAnimationFrame(f);
    else { const dt = (performance.now() - t0) / 1000;
      done({ fps: n / dt, received: ((V.framesReceived || 0) - r0) / dt, applied: ((V.deforms || 0) - d0) / dt,
             deform_ms: ((V.deformMs || 0) - m0) / Math.max(1, (V.deforms || 0) - d0) }); } }
  requestAnimationFrame(f); })"""


def _torus(nv: int) -> tuple[np.ndarray, np.ndarray]:
    m = max(8, int(round(np.sqrt(nv / 2))))
    n = max(8, nv // m)
    u, v = np.meshgrid(np.linspace(0, 2 * np.pi, n, endpoint=False), np.linspace(0, 2 * np.pi, m, endpoint=False),
                       indexing="ij")
    R, r = 0.1, 0.04  # [m]
    X = np.stack([(R + r * np.cos(v)) * np.cos(u), (R + r * np.cos(v)) * np.sin(u), r * np.sin(v)], -1).reshape(-1, 3)
    i, j = np.meshgrid(np.arange(n), np.arange(m), indexing="ij")
    a, b = i * m + j, ((i + 1) % n) * m + j
    c, d = i * m + (j + 1) % m, ((i + 1) % n) * m + (j + 1) % m
    T = np.concatenate([np.stack([a, b, d], -1).reshape(-1, 3), np.stack([a, d, c], -1).reshape(-1, 3)])
    return X, T


def _pump(update, stop: threading.Event, times: list) -> None:
    period, k = 1.0 / RATE, 0
    t_next = time.perf_counter()
    while not stop.is_set():
        t0 = time.perf_counter()
        update(k)
        times.append(time.perf_counter() - t0)
        k += 1
        t_next += period
        stop.wait(max(0.0, t_next - time.perf_counter()))


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def measure(browser, kind: str, nv: int, r: int, seconds: float) -> dict:
    """One case (``kind`` in q, positions, viser) on a Playwright ``browser``; returns the figures."""
    X, T = _torus(nv)
    rng = np.random.default_rng(0)
    shapes = 1e-3 * rng.standard_normal((3 * len(X), r))
    omega = 2 * np.pi * (0.5 + rng.random(r))

    def q_at(k):
        return np.sin(omega * k / RATE)

    times: list[float] = []
    stop = threading.Event()
    out: dict = {"kind": kind, "nv": len(X), "r": r}
    if kind == "viser":
        import viser

        server = viser.ViserServer(host="127.0.0.1", port=_free_port(), verbose=False)
        handle = server.scene.add_mesh_simple("/body", vertices=X.astype(np.float32), faces=T.astype(np.uint32))
        url, close = f"http://127.0.0.1:{server.get_port()}/", server.stop

        def update(k):
            handle.vertices = (X + (shapes @ q_at(k)).reshape(-1, 3)).astype(np.float32)
        out["bytes"] = 12 * len(X)  # float32 positions (before viser's own message framing)
    else:
        from modalfem.view import Viewer

        viewer = Viewer(fps=RATE)
        viewer.add_body(X, T, shapes=shapes if kind == "q" else None)
        viewer.start()
        url, close = viewer.url, viewer.close
        if kind == "q":
            def update(k):
                viewer.update(0, q=q_at(k))
        else:
            def update(k):
                viewer.update(0, positions=X + (shapes @ q_at(k)).reshape(-1, 3))
        update(0)
        out["bytes"] = len(json.dumps(viewer._frame()[1]))
    page = browser.new_page(viewport={"width": 800, "height": 600})
    try:
        page.goto(url)
        if kind == "viser":
            page.wait_for_function("() => document.querySelector('canvas') !== null", timeout=60000)
        else:
            page.wait_for_function("() => window.modalfemViewer.ready && window.modalfemViewer.framesDrawn > 2",
                                   timeout=60000)
        thread = threading.Thread(target=_pump, args=(update, stop, times), daemon=True)
        thread.start()
        page.wait_for_timeout(4000 if kind == "viser" else 1000)  # viser's page builds its React app first
        n0 = len(times)
        out.update(page.evaluate(_COUNT_JS, seconds))
        out["server_ms"] = 1e3 * float(np.median(times[n0:])) if len(times) > n0 else float("nan")
        stop.set()
        thread.join()
    finally:
        page.close()
        close()
    if kind == "viser":
        out["received"] = out["applied"] = out["deform_ms"] = None
    return out


def _f(x, fmt: str) -> str:
    return "-" if x is None or (isinstance(x, float) and not np.isfinite(x)) else format(x, fmt)


def render(cases: list[dict], *, command: str, date: str, machine: str, load: tuple, versions: dict) -> str:
    """The markdown section (starts with ``SECTION``)."""
    L = [SECTION, "",
         f"`{command}` on {date}; {machine}; load average (1 min) {load[0]:.2f} before, {load[1]:.2f} after "
         f"(other work on the machine slows every case alike; compare ratios within one size). "
         f"{', '.join(f'{k} {v}' for k, v in versions.items())}. Headless Chromium with software WebGL "
         f"(SwiftShader), 800 x 600, {RATE:.0f} updates/s sent, {MODES} modes, every modal coordinate changing.",
         "",
         "| vertices | frames carry | bytes/frame | server ms/update | frames received/s | page ms/update | page fps | fps / q fps |",
         "|---:|---|---:|---:|---:|---:|---:|---:|"]
    for c in cases:
        ref = next((d for d in cases if d["nv"] == c["nv"] and d["kind"] == "q"), None)
        ratio = f"{c['fps'] / ref['fps']:.2f}x" if ref and ref["fps"] > 0 else "-"
        L.append(f"| {c['nv']} | {c['kind']} | {c['bytes']} | {_f(c['server_ms'], '.2f')} | {_f(c['received'], '.1f')} "
                 f"| {_f(c['deform_ms'], '.2f')} | {c['fps']:.1f} | {ratio} |")
    skipped = [c for c in cases if c.get("skipped")]
    L += ["", "`q`: the page deforms the surface itself from the r modal coordinates, in its vertex shader (what "
          "`modalfem view` sends); `positions`: the server sends float32 positions and the page computes normals "
          "(what a body without modes needs); `viser`: the peer library, positions set on its mesh handle. "
          "page ms/update is the page's JavaScript time to apply one frame (for `q`: the upload of r numbers; "
          "the shader's work shows in the fps)."]
    if skipped:
        L.append(skipped[0]["skipped"])
    elif any(c["kind"] == "viser" for c in cases):
        L.append("viser is not a dependency of modalfem; it was installed beside it for this run (pip install viser).")
    return "\n".join(L) + "\n"


def command(argv: list[str]) -> int:
    """``modalfem bench view [--out BENCHMARKS.md] [--seconds S] [--quick]``."""
    ap = argparse.ArgumentParser(prog="modalfem bench view",
                                 description="Live viewer: frames carrying q vs positions (and the viser peer).")
    ap.add_argument("--out", default="BENCHMARKS.md", help="markdown file whose view section is replaced")
    ap.add_argument("--seconds", type=float, default=4.0, help="measuring window per case [s]")
    ap.add_argument("--quick", action="store_true", help="one small size (smoke test)")
    a = ap.parse_args(argv)
    from modalfem.bench.cli import _machine, update_section
    from modalfem.errors import InputError

    if not os.path.exists(CHROMIUM):
        raise InputError(f"no Chromium at {CHROMIUM} (Debian: apt-get install chromium; or set MODALFEM_CHROMIUM)")
    try:
        from playwright.sync_api import sync_playwright
    except ImportError:
        raise InputError("the view benchmark needs playwright (pip install playwright)") from None
    try:
        import viser

        kinds, versions = ("q", "positions", "viser"), {"viser": viser.__version__}
    except ImportError:
        kinds, versions = ("q", "positions"), {}
    import importlib.metadata as md

    versions = {"playwright": md.version("playwright"), **versions}
    load0 = os.getloadavg()[0]
    cases = []
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=["--enable-unsafe-swiftshader", "--no-sandbox"])
        versions = {"chromium": browser.version, **versions}
        try:
            for nv in ((2000,) if a.quick else VERTICES):
                for kind in kinds:
                    print(f"[bench view] {nv} vertices, frames carry {kind}", file=sys.stderr, flush=True)
                    cases.append(measure(browser, kind, nv, MODES, 1.0 if a.quick else a.seconds))
        finally:
            browser.close()
    if "viser" not in kinds:
        cases[-1]["skipped"] = "viser is not installed here, so the peer rows are missing (pip install viser)."
    cmd = "python -m modalfem bench view" + ("" if not argv else " " + shlex.join(argv))
    date = _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    section = render(cases, command=cmd, date=date, machine=_machine(), load=(load0, os.getloadavg()[0]),
                     versions=versions)
    print(section)
    update_section(a.out, section)
    return 0


if __name__ == "__main__":
    sys.exit(command(sys.argv[1:]))
