"""Local process pools from a user's script: a script without an ``if __name__ == "__main__":`` guard would be rerun
by every forkserver/spawn worker (and wait on the locks its parent holds: a silent hang), so its tasks run in the
calling process with a warning; a guarded script gets the pool."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap

BODY = """
import warnings
from metafovea.parallel import get_executor, run_tasks
with warnings.catch_warnings(record=True) as w:
    warnings.simplefilter("always")
    ex = get_executor(2)
    res = sorted(dict(run_tasks(abs, [-1, -2, -3], executor=ex)).values())
    print(type(ex).__name__, res, any("has no `if __name__" in str(x.message) for x in w))
    ex.shutdown()
"""


def _run(tmp_path, guarded: bool) -> str:
    src = ("if __name__ == '__main__':\n" + textwrap.indent(BODY, "    ")) if guarded else BODY
    script = tmp_path / ("guarded.py" if guarded else "plain.py")
    script.write_text(src)
    env = {**os.environ, "METAFOVEA_CACHE": str(tmp_path / "cache")}
    return subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=120, env=env,
                          cwd=tmp_path).stdout


def test_an_unguarded_script_runs_its_tasks_in_process_with_a_warning(tmp_path):
    assert _run(tmp_path, guarded=False).split() == ["SerialExecutor", "[1,", "2,", "3]", "True"]


def test_a_guarded_script_gets_the_process_pool(tmp_path):
    assert _run(tmp_path, guarded=True).split() == ["ProcessPoolExecutor", "[1,", "2,", "3]", "False"]
