"""Fixtures of the tools' tests: a file of tools/ loaded as a module."""
import importlib.util
from pathlib import Path

import pytest

TOOLS = Path(__file__).resolve().parents[2] / "tools"


@pytest.fixture(scope="session")
def load_tool():
    """load_tool('research/compare_sensor.py') -> that file of tools/ as a module, loaded as when it runs as a script:
    with its folder first on sys.path, so that its imports of the modules beside it resolve."""
    def load(relative: str):
        path = TOOLS / relative
        with pytest.MonkeyPatch.context() as patch:
            patch.syspath_prepend(str(path.parent))
            spec = importlib.util.spec_from_file_location(path.stem, path)
            module = importlib.util.module_from_spec(spec)
            spec.loader.exec_module(module)
        return module
    return load
