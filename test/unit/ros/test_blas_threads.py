"""Every node keeps OpenBLAS to one thread, even where the user's environment says nothing: its waiting
threads spin and starve the robot's other processes (``aruco_abs_orient/__init__`` has the figures).

Each script in ``scripts/`` is run up to its ``main()`` call in a fresh interpreter, and asked how many
threads each OpenBLAS it loaded uses (numpy's and the system's: their own ``openblas_get_num_threads``,
found through ``/proc/self/maps``, as threadpoolctl does). A plain ``import numpy`` beside it shows the
probe sees the default, one thread per core.
"""
import os
import subprocess
import sys
from pathlib import Path

import pytest

SCRIPTS = Path(__file__).resolve().parents[3] / "scripts"
PROBE = """
import ctypes
threads = {}
for path in {line.split()[-1] for line in open("/proc/self/maps") if "openblas" in line.lower()}:
    lib = ctypes.CDLL(path)
    for name in ("openblas_get_num_threads", "openblas_get_num_threads64_", "scipy_openblas_get_num_threads64_"):
        if hasattr(lib, name):
            threads[path] = getattr(lib, name)()
print(threads)
print("OPENBLAS_THREADS", max(threads.values()))
"""


def openblas_threads(code: str) -> int:
    env = {k: v for k, v in os.environ.items() if k not in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS")}
    out = subprocess.run([sys.executable, "-c", code + "\nimport numpy\n" + PROBE], env=env, text=True,
                         stdout=subprocess.PIPE, stderr=subprocess.STDOUT, timeout=120)
    assert out.returncode == 0, out.stdout[-3000:]
    return int(out.stdout.split("OPENBLAS_THREADS")[-1])


def test_the_probe_sees_openblas_default_threads():
    if (os.cpu_count() or 1) < 2:
        pytest.skip("one core: OpenBLAS's default is one thread")
    assert openblas_threads("") > 1


@pytest.mark.parametrize("script", sorted(p.name for p in SCRIPTS.iterdir()))
def test_every_node_runs_openblas_on_one_thread(script):
    lines = (SCRIPTS / script).read_text().splitlines()
    body = "\n".join(line for line in lines if "main()" not in line)  # its imports, not its run
    assert "import" in body
    assert openblas_threads(body) == 1
