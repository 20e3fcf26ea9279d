"""Scene tests: one model cache per test session (modes computed once, never the user's ~/.cache)."""

import pytest


@pytest.fixture(scope="session", autouse=True)
def _model_cache(tmp_path_factory):
    mp = pytest.MonkeyPatch()
    mp.setenv("MODALFEM_CACHE", str(tmp_path_factory.mktemp("model-cache")))
    yield
    mp.undo()
