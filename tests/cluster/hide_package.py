"""``dask worker --preload`` module: the worker process behaves as if this package were not
installed (an environment without it), so tests need no second virtual environment."""

import sys

HIDDEN = ("pipeline", "box_core")


class _HidePackage:
    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] in HIDDEN:
            raise ModuleNotFoundError(f"No module named {name!r}", name=name)
        return None


for _name in [m for m in sys.modules if m.split(".")[0] in HIDDEN]:
    del sys.modules[_name]
sys.meta_path.insert(0, _HidePackage())
