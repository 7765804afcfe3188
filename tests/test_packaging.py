"""senerf as a user installs it (not editable): the distribution carries the K-Planes kernel's C source, and the
installed package compiles and runs the kernel."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import tarfile
import venv
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

# Runs in the fresh venv, away from the repository: the installed senerf compiles its kernel into $SENERF_CACHE and a
# fused K-Planes field matches the pure-PyTorch one, values and gradients.
CHECK = """
import sys
from pathlib import Path
import torch
import senerf
from senerf.fields import KPlanesField, ckernel
assert Path(senerf.__file__).resolve().is_relative_to(Path(sys.prefix).resolve()), senerf.__file__
assert ckernel.cpu_planes_path() == "compiled", ckernel.kernel_status()
assert ckernel.cpu_planes_warning() is None
fields = [KPlanesField([[-1.0] * 3, [1.0] * 3], resolution=8, multires=(1, 2), backend=b) for b in ("fused", "gather")]
xyz = torch.rand(4096, 3, generator=torch.Generator().manual_seed(0)) * 2 - 1
feats = [f.features(xyz)[0] for f in fields]
torch.testing.assert_close(feats[0], feats[1])
grads = [torch.autograd.grad(x.square().sum(), f.table)[0] for x, f in zip(feats, fields)]
torch.testing.assert_close(grads[0], grads[1])
print("compiled kernel ran from", Path(senerf.__file__).parent)
"""


def _run(cmd, cwd, env=None):
    done = subprocess.run([str(c) for c in cmd], cwd=cwd, env=env, capture_output=True, text=True, timeout=240)
    assert done.returncode == 0, f"{cmd}\n{done.stdout}\n{done.stderr}"
    return done.stdout


@pytest.mark.skipif(not (os.environ.get("CC") or shutil.which("cc") or shutil.which("gcc")),
                    reason="no C compiler on PATH or in $CC: the installed kernel cannot be built here")
def test_an_sdist_and_its_wheel_installed_into_a_fresh_venv_run_the_compiled_kernel(tmp_path):
    # Catches: the C source left out of the sdist or the wheel (every fit silently took the slower pure-PyTorch
    # path), or the kernel built or cached inside the installed package, which may be read-only.
    tree = tmp_path / "tree"   # a copy, so the build leaves nothing in the repository
    shutil.copytree(ROOT / "senerf", tree / "senerf", ignore=shutil.ignore_patterns("__pycache__", "*.so", "*.pyc"))
    for name in ("pyproject.toml", "README.md"):
        shutil.copy2(ROOT / name, tree / name)
    dist = tmp_path / "dist"
    build = f"import setuptools.build_meta as b; print(b.build_sdist({str(dist)!r}))"
    sdist = dist / _run([sys.executable, "-c", build], cwd=tree).strip().splitlines()[-1]
    with tarfile.open(sdist) as tar:
        assert any(n.endswith("/senerf/fields/_kplanes_kernel.c") for n in tar.getnames())

    env_dir = tmp_path / "venv"
    venv.EnvBuilder(with_pip=False).create(env_dir)
    python = env_dir / ("Scripts/python.exe" if os.name == "nt" else "bin/python")
    site = Path(_run([python, "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"], cwd=tmp_path).strip())
    # torch, numpy, pip and setuptools come from this environment (a venv or not), after the venv's own packages;
    # the .pth files there, such as the editable install's, are not run
    outer = [p for p in sys.path if Path(p).name in ("site-packages", "dist-packages")]
    (site / "outer-environment.pth").write_text("\n".join(outer) + "\n")
    # pip builds a wheel from the sdist and installs it into the venv
    _run([python, "-m", "pip", "install", "--no-deps", "--no-build-isolation", "--no-index", "--ignore-installed",
          "--quiet", "--disable-pip-version-check", sdist], cwd=tmp_path)
    assert (site / "senerf" / "fields" / "_kplanes_kernel.c").is_file()

    cache = tmp_path / "cache"
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "SENERF_CACHE")}
    env["SENERF_CACHE"] = str(cache)
    out = _run([python, "-c", CHECK], cwd=tmp_path, env=env)
    assert f"compiled kernel ran from {site / 'senerf'}" in out, out
    assert list(cache.glob("kplanes_float_f16_*.so"))                  # built into the cache ...
    assert not list((site / "senerf").rglob("*.so"))                   # ... and nothing beside the installed source
