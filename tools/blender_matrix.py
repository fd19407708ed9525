"""The Blenders the extension is tested in: one bpy wheel per supported Blender line.

tests/test_packaging.py installs the built zip into each Blender whose Python is the one
running the suite (so ``tools/test.sh`` covers 4.2, 4.5 and 5.0 on Python 3.11 and
``tools/test.sh --py313`` covers 5.1 and 5.2 on Python 3.13; ``.ci/run`` runs both).

Each Blender runs in its own venv outside the repository,
``$PDIC_BLENDER_VENVS`` or ``~/.cache/pdic/blenders/bpy-<version>``, holding the bpy wheel
and what it needs (numpy as pinned in that Python's requirements file) and nothing else:
scipy, embreex and xatlas must come from the wheels the extension unpacks, never from the
venv. A venv is created on first use (about 1 minute: the bpy wheel is 350-520 MB) and
reused afterwards; a stamp records what was installed.

    .venv/bin/python tools/blender_matrix.py            # list the Blenders and their venvs
    .venv/bin/python tools/blender_matrix.py --setup    # create the venvs of this Python's Blenders
"""
from __future__ import annotations

import argparse
import fcntl
import hashlib
import os
import re
import shutil
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
# Python -> the requirements file whose numpy (and transitive) pins a Blender of that Python gets.
REQUIREMENTS = {"3.11": ROOT / "requirements.txt", "3.13": ROOT / "requirements-py313.txt"}
# Packages a test Blender's venv must not hold: the extension brings them as wheels.
BUNDLED = ("scipy", "embreex", "xatlas")


@dataclass(frozen=True)
class Blender:
    """One Blender release as a bpy wheel on PyPI."""

    line: str    # the release line users know, e.g. "4.2 LTS"
    bpy: str     # the bpy wheel version tested
    python: str  # the CPython minor version the wheel is built for

    @property
    def id(self) -> str:
        return f"bpy-{self.bpy}"


BLENDERS = (
    # 4.2.13: the oldest 4.2 patch on PyPI that unpacks only the wheels of its own Python
    # (4.2.0 unpacks all of them); blender_manifest.toml's blender_version_min.
    Blender("4.2 LTS", "4.2.13", "3.11"),
    Blender("4.5 LTS", "4.5.15", "3.11"),
    Blender("5.0", "5.0.1", "3.11"),
    Blender("5.1", "5.1.2", "3.13"),
    Blender("5.2 LTS", "5.2.3", "3.13"),
)


def this_python() -> str:
    return "%d.%d" % sys.version_info[:2]


def for_python(python: str | None = None) -> tuple[Blender, ...]:
    """The Blenders built for ``python`` (default: the running interpreter's)."""
    python = python or this_python()
    return tuple(b for b in BLENDERS if b.python == python)


def venv_root() -> Path:
    if env := os.environ.get("PDIC_BLENDER_VENVS"):
        return Path(env)
    return Path.home() / ".cache" / "pdic" / "blenders"


def constraints(python: str) -> list[str]:
    """The ``name==version`` pins of ``python``'s requirements file, less bpy and the bundled packages."""
    pins = []
    for line in REQUIREMENTS[python].read_text().splitlines():
        m = re.match(r"^\s*([A-Za-z0-9_.\-]+)\s*==\s*([^\s;#]+)", line)
        if m and m.group(1).lower() not in {"bpy", "pytest", *BUNDLED}:
            pins.append(f"{m.group(1)}=={m.group(2)}")
    return pins


def _stamp(blender: Blender) -> str:
    text = "\n".join([blender.bpy, sys.version.split()[0], *constraints(blender.python)])
    return hashlib.sha256(text.encode()).hexdigest()


def interpreter(blender: Blender, log=print) -> Path:
    """The Python of ``blender``'s venv, created (bpy + numpy, nothing bundled) when missing or stale.

    Must run on the same CPython minor version as ``blender``: its venv is made from this
    interpreter's base.
    """
    if blender.python != this_python():
        raise RuntimeError(f"{blender.id} needs Python {blender.python}, this is {this_python()}")
    venv = venv_root() / blender.id
    python = venv / "bin" / "python"
    stamp = venv / ".pdic-stamp"
    venv_root().mkdir(parents=True, exist_ok=True)
    with open(venv_root() / f".{blender.id}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # two suites setting up the same venv wait for each other
        if python.is_file() and stamp.is_file() and stamp.read_text() == _stamp(blender):
            return python
        log(f"blender_matrix: creating {venv} (bpy=={blender.bpy}, Blender {blender.line})")
        shutil.rmtree(venv, ignore_errors=True)
        base = getattr(sys, "_base_executable", sys.executable)
        subprocess.run([base, "-m", "venv", str(venv)], check=True)
        constraint_file = venv / "constraints.txt"
        constraint_file.write_text("\n".join(constraints(blender.python)) + "\n")
        proc = subprocess.run(
            [str(python), "-m", "pip", "install", "--disable-pip-version-check", "-q",
             f"bpy=={blender.bpy}", "-c", str(constraint_file)],
            capture_output=True, text=True,
        )
        if proc.returncode != 0:
            raise RuntimeError(f"pip could not install bpy=={blender.bpy} into {venv}:\n{proc.stderr[-3000:]}")
        stamp.write_text(_stamp(blender))
    return python


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--setup", action="store_true", help="create the venvs of this Python's Blenders")
    args = parser.parse_args(argv)
    for blender in BLENDERS:
        mine = blender.python == this_python()
        where = interpreter(blender) if (args.setup and mine) else venv_root() / blender.id / "bin" / "python"
        print(f"Blender {blender.line:8s} bpy=={blender.bpy:7s} Python {blender.python}  {where}"
              + ("" if mine else "  (other Python)"))
    return 0


if __name__ == "__main__":
    sys.exit(main())
