"""numba's on-disk cache and the kernels that call compiled functions of other modules.

numba keeps a compiled function in ``__pycache__`` and reuses it while the function's own
source file keeps its stamp; a compiled function it calls from another file is linked into
the cached code and not looked at again.  So a module whose kernels call another module's
(``compiled_rrt`` the scan of ``collide``) names the digest of that file in ``LINKED``, and
any change to the file must change that line as well: the dependent file's stamp then
changes too, and numba compiles its kernels afresh instead of running the old code.
"""

from __future__ import annotations

import ast
import hashlib
import importlib
from pathlib import Path

import pytest
from numba.core.registry import CPUDispatcher

SIM = Path(__file__).resolve().parents[1] / "pipeline" / "sim"


def digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()[:16]


def _is_njit(decorator: ast.expr) -> bool:
    target = decorator.func if isinstance(decorator, ast.Call) else decorator
    return isinstance(target, ast.Name) and target.id == "njit"


def linked_modules(name: str) -> set[str]:
    """The files of pipeline/sim whose compiled functions the compiled functions of module
    ``name`` call (``module.function(...)`` inside an ``@njit`` function)."""
    module = importlib.import_module(f"pipeline.sim.{name}")
    tree = ast.parse((SIM / f"{name}.py").read_text())
    found = set()
    for fn in ast.walk(tree):
        if not (isinstance(fn, ast.FunctionDef) and any(map(_is_njit, fn.decorator_list))):
            continue
        for node in ast.walk(fn):
            if not (isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name)):
                continue
            other = getattr(module, node.value.id, None)
            if (getattr(other, "__name__", "").startswith("pipeline.sim.")
                    and isinstance(getattr(other, node.attr, None), CPUDispatcher)):
                found.add(Path(other.__file__).name)
    return found


KERNEL_MODULES = sorted(p.stem for p in SIM.glob("*.py") if "@njit" in p.read_text())


def test_the_kernel_modules_are_found():
    assert {"collide", "compiled_rrt", "fast_distance"} <= set(KERNEL_MODULES)
    assert linked_modules("compiled_rrt") == {"collide.py"}


@pytest.mark.parametrize("name", KERNEL_MODULES)
def test_every_linked_module_is_named_with_its_current_digest(name):
    module = importlib.import_module(f"pipeline.sim.{name}")
    declared = getattr(module, "LINKED", {})
    linked = linked_modules(name)
    assert set(declared) == linked, (
        f"pipeline/sim/{name}.py: its kernels call compiled functions of {sorted(linked)}; "
        f"LINKED names {sorted(declared)}")
    stale = {f: digest(SIM / f) for f in linked if declared[f] != digest(SIM / f)}
    assert not stale, (
        f"pipeline/sim/{name}.py links code of files changed since its LINKED digests were "
        f"written (numba would go on running the old code from its cache); set them to "
        f"{stale}")


def test_numba_runs_a_linked_function_s_old_code_from_its_cache(tmp_path):
    """The premise of ``LINKED``: after a change to a called module alone, numba's cache
    still runs the old callee inside the caller (should a numba release check the
    callees' files too, this fails and ``LINKED`` is no longer needed)."""
    import os
    import subprocess
    import sys

    (tmp_path / "callee.py").write_text(
        "from numba import njit\n\n@njit(cache=True)\ndef f():\n    return 1\n")
    (tmp_path / "caller.py").write_text(
        "from numba import njit\nimport callee\n\n@njit(cache=True)\ndef g():\n"
        "    return callee.f()\n")
    env = {**os.environ, "PYTHONPATH": str(tmp_path), "NUMBA_CACHE_DIR": str(tmp_path / "c")}

    def run() -> str:
        return subprocess.run([sys.executable, "-c", "import caller, callee; "
                               "print(caller.g(), callee.f())"], env=env, cwd=tmp_path,
                              capture_output=True, text=True, check=True).stdout.split()

    assert run() == ["1", "1"]
    callee = tmp_path / "callee.py"
    callee.write_text(callee.read_text().replace("return 1", "return 2"))
    stat = callee.stat()
    os.utime(callee, ns=(stat.st_atime_ns, stat.st_mtime_ns + 10**9))  # a newer stamp
    assert run() == ["1", "2"]
