"""Browser assets of modalfem: three.js (bundled, MIT), the JavaScript modal runtime and the export page.

* ``three.bundle.min.js``: three.js with GLTFLoader and OrbitControls as one classic script (global
  ``THREE``), built by ``scripts/build_three_bundle.sh`` from npm (version: ``THREE_VERSION``;
  licence: ``THREE_LICENSE``);
* ``modal.js``: exact per-mode damped oscillators, surface impulses and modal sound (global
  ``ModalRuntime``; also a node module);
* ``page.js`` + ``page.html``: the self-contained page of ``modalfem export --html``.

``asset(name)`` returns a file's text; ``inline_script(text)`` makes JavaScript safe to inline in a
``<script>`` element.
"""

from __future__ import annotations

from importlib import resources

__all__ = ["ASSETS", "THREE_REVISION", "THREE_VERSION", "asset", "inline_script"]

#: npm version of the bundled three.js, and its REVISION
THREE_VERSION = "0.187.0"
THREE_REVISION = "187"
ASSETS = ("three.bundle.min.js", "modal.js", "page.js", "page.html", "THREE_LICENSE")


def asset(name: str) -> str:
    """The text of the packaged asset ``name`` (one of ``ASSETS``)."""
    if name not in ASSETS:
        raise ValueError(f"unknown web asset {name!r}; known: {', '.join(ASSETS)}")
    return resources.files(__name__).joinpath(name).read_text(encoding="utf-8")


def inline_script(text: str) -> str:
    """JavaScript ``text`` made safe inside ``<script>...</script>``: every ``</`` becomes ``<\\/``
    (the same string, regular expression or comment to the JavaScript parser; HTML no longer sees
    an end tag)."""
    return text.replace("</", "<\\/")
