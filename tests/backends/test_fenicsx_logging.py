"""FEniCSx backend and logging: FFCx's captureWarnings and a cold JIT's build log must not leak.

Importing FFCx calls ``logging.captureWarnings(True)`` and a cold JIT cache makes the cffi build log
``INFO:root:running build_ext`` and the gcc command lines. After a FEniCSx assembly, warnings must
reach ``warnings``/``pytest.warns`` again and nothing of the build may reach stderr, unless the
CLI's ``--verbose`` asks for it.
"""

from __future__ import annotations

import json
import logging
import os
import subprocess
import sys
import warnings

import pytest

pytestmark = pytest.mark.fenicsx

pytest.importorskip("dolfinx", reason="needs Debian's python3-dolfinx")


def _chatter(text: str) -> list[str]:
    return [ln for ln in text.splitlines() if "INFO:" in ln or "gcc" in ln or "build_ext" in ln]


def test_warnings_reach_pytest_after_a_cold_jit(tmp_path, monkeypatch, capfd):
    import dolfinx.jit

    import modalfem
    from modalfem.backends import fenicsx
    from modalfem.mesh import box

    # a cold cache: every form and element of this assembly is compiled by gcc now
    monkeypatch.setitem(dolfinx.jit.DOLFINX_DEFAULT_JIT_PARAMETERS, "cache_dir", (tmp_path / "jit", "test"))
    root_level = logging.getLogger().level
    with pytest.warns(RuntimeWarning, match="reaches pytest"):
        logging.captureWarnings(True)  # what the first import of FFCx (dolfinx) in a process does
        K, M = fenicsx.assemble(box(size=(0.2, 0.05, 0.05), cells=(2, 1, 1)), modalfem.STEEL, degree=1)
        warnings.warn("this warning reaches pytest", RuntimeWarning)
    assert K.shape == M.shape == (36, 36)
    assert any((tmp_path / "jit").glob("*.so")), "the JIT cache was not cold"
    assert logging.getLogger().level == root_level
    err = capfd.readouterr().err
    assert not _chatter(err), err
    assert "py.warnings" not in err


FRESH = """
import json, sys, warnings
with warnings.catch_warnings(record=True) as caught:
    warnings.simplefilter("always")
    import modalfem  # noqa: E402
    from modalfem.backends import fenicsx
    from modalfem.mesh import box
    fenicsx.assemble(box(size=(0.2, 0.05, 0.05), cells=(2, 1, 1)), modalfem.STEEL, degree=1)
    warnings.warn("after the JIT", RuntimeWarning)
print(json.dumps([str(w.message) for w in caught if w.category is RuntimeWarning]))
"""


def test_fresh_process_cold_jit_keeps_warnings_and_stderr_clean(tmp_path):
    """The real case: dolfinx and FFCx are first imported inside ``catch_warnings``, the cache is cold."""
    env = dict(os.environ, XDG_CACHE_HOME=str(tmp_path / "cache"))
    env.pop("MODALFEM_VERBOSE", None)
    r = subprocess.run([sys.executable, "-c", FRESH], capture_output=True, text=True, timeout=600, check=False, env=env)
    assert r.returncode == 0, r.stderr
    assert json.loads(r.stdout.splitlines()[-1]) == ["after the JIT"]
    assert any((tmp_path / "cache" / "fenics").glob("*.so")), "the JIT cache was not cold"
    assert not _chatter(r.stderr) and "py.warnings" not in r.stderr, r.stderr


def _cli(tmp_path, *extra):
    env = dict(os.environ, XDG_CACHE_HOME=str(tmp_path / "cache"))
    env.pop("MODALFEM_VERBOSE", None)
    js = tmp_path / "s.json"
    r = subprocess.run(
        [sys.executable, "-m", "modalfem", "modes", "box", "--size", "0.2", "0.05", "0.05", "--cells", "2", "1", "1",
         "-k", "1", "--degree", "1", "--fixed", "x0", "--backend", "fenicsx", "--solver", "scipy", "--json", str(js),
         *extra],
        capture_output=True, text=True, timeout=600, check=False, env=env,
    )
    assert r.returncode == 0, r.stderr
    assert json.loads(js.read_text())["backend"] == "fenicsx"
    assert any((tmp_path / "cache" / "fenics").glob("*.so")), "the JIT cache was not cold"
    return r.stderr


def test_cli_hides_the_jit_build_log_unless_verbose(tmp_path):
    quiet = _cli(tmp_path / "a")
    assert not _chatter(quiet), quiet
    assert "assembly (fenicsx" in quiet  # progress lines are still there
    verbose = _cli(tmp_path / "b", "--verbose")
    assert any("INFO:root:running build_ext" in ln for ln in verbose.splitlines()), verbose
    assert any("gcc" in ln for ln in _chatter(verbose)), verbose
