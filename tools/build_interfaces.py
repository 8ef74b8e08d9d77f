#!/usr/bin/env python3
"""Build the project's ROS 2 interface packages (``interfaces/``) into a virtual environment.

The ros-jazzy-* wheels make the venv a ROS install prefix (libraries in ``lib``, CMake configs
and the ament index in ``share``). This script configures, builds and installs each package in
``interfaces/`` with CMake + Ninja into that prefix, in dependency order (geographic_msgs, then
nav2_msgs), so that ``from nav2_msgs.action import NavigateThroughPoses`` works in the venv.

Skips:
  * the whole build when a ``nav2_msgs`` that this project did not build is already importable
    (a real ROS install): that one is used and nothing is built;
  * a single package when one of the same name from elsewhere is importable (geographic_msgs);
  * the whole build when the stamp ``<venv>/.fleet-interfaces.stamp`` holds the hash of the
    interface sources and this script (``--force`` rebuilds).

Exit status: 0 when the interfaces are importable afterwards, 1 on a build failure (the
failing command and the tail of its log are printed), 2 on bad usage.

Usage: ``python tools/build_interfaces.py --venv .venv [--jobs N] [--force]``
"""

from __future__ import annotations

import argparse
import hashlib
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
INTERFACES = ROOT / "interfaces"
# Dependency order.
PACKAGES = ("geographic_msgs", "tf2_msgs", "nav2_msgs")
MARKER = "fleet-orchestrator"  # appears in the package.xml of the packages built here
STAMP_NAME = ".fleet-interfaces.stamp"


def log(msg: str) -> None:
    print(f"[build-interfaces] {msg}", flush=True)


def source_hash(packages: tuple[str, ...] = PACKAGES) -> str:
    """SHA-256 over every file of the interface packages, the shared CMake and this script."""
    h = hashlib.sha256()
    files = sorted(p for p in INTERFACES.rglob("*") if p.is_file() and "__pycache__" not in p.parts)
    files.append(Path(__file__).resolve())
    files.append(Path(__file__).resolve().parent / "rosidl_fixups" / "sitecustomize.py")
    for f in files:
        rel = f.relative_to(ROOT) if f.is_relative_to(ROOT) else f
        if f.is_relative_to(INTERFACES) and rel.parts[1] not in packages + ("cmake",):
            continue
        h.update(str(rel).encode())
        h.update(b"\0")
        h.update(f.read_bytes())
        h.update(b"\0")
    h.update(",".join(packages).encode())
    return h.hexdigest()


def build_env(venv: Path) -> dict[str, str]:
    """Environment for CMake and the rosidl generators: the venv as the only ROS prefix."""
    env = dict(os.environ)
    env["PATH"] = f"{venv / 'bin'}{os.pathsep}{env.get('PATH', '')}"
    env["AMENT_PREFIX_PATH"] = str(venv)
    env["CMAKE_PREFIX_PATH"] = str(venv)
    env["LD_LIBRARY_PATH"] = f"{venv / 'lib'}{os.pathsep}{env.get('LD_LIBRARY_PATH', '')}"
    env["VIRTUAL_ENV"] = str(venv)
    # rosidl_parser fix for actions whose result and feedback share a constant (see the module).
    fixups = str(Path(__file__).resolve().parent / "rosidl_fixups")
    env["PYTHONPATH"] = fixups + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    env.pop("PYTHONHOME", None)
    return env


def locate_package(venv: Path, name: str) -> tuple[bool, bool]:
    """Return (importable, built_here) for the interface package ``name`` in ``venv``'s Python."""
    code = (
        "import sys\n"
        f"try:\n import {name}\nexcept Exception:\n print('none'); sys.exit()\n"
        "from ament_index_python.packages import get_package_share_directory as g\n"
        "import pathlib\n"
        f"try:\n p = pathlib.Path(g('{name}')) / 'package.xml'\n"
        f" print('ours' if '{MARKER}' in p.read_text() else 'real')\n"
        "except Exception:\n print('real')\n"
    )
    out = subprocess.run(
        [str(venv / "bin" / "python"), "-c", code], capture_output=True, text=True, env=build_env(venv)
    ).stdout.strip()
    last = out.splitlines()[-1] if out else "none"
    return last != "none", last == "ours"


def run(cmd: list[str], log_file: Path, env: dict[str, str]) -> None:
    with open(log_file, "ab") as fh:
        fh.write(("\n$ " + " ".join(cmd) + "\n").encode())
        fh.flush()
        proc = subprocess.run(cmd, stdout=fh, stderr=subprocess.STDOUT, env=env)
    if proc.returncode != 0:
        tail = log_file.read_text(errors="replace").splitlines()[-40:]
        raise RuntimeError(
            f"command failed (exit {proc.returncode}): {' '.join(cmd)}\n"
            f"--- last lines of {log_file} ---\n" + "\n".join(tail)
        )


def build_package(
    name: str, venv: Path, prefix: Path, build_root: Path, jobs: int, src_root: Path = INTERFACES
) -> float:
    """Configure, build and install one interface package into ``prefix``; return seconds taken.

    ``venv`` provides the Python interpreter and the ROS wheels (CMake finds dependencies in
    ``prefix`` first, then in ``venv``). Raises ``RuntimeError`` with the log tail on failure.
    """
    t0 = time.monotonic()
    src = src_root / name
    bdir = build_root / name
    bdir.mkdir(parents=True, exist_ok=True)
    log_file = build_root / f"{name}.log"
    log_file.write_text("")
    env = build_env(venv)
    if prefix != venv:
        env["AMENT_PREFIX_PATH"] = f"{prefix}{os.pathsep}{venv}"
        env["CMAKE_PREFIX_PATH"] = f"{prefix}{os.pathsep}{venv}"
        env["LD_LIBRARY_PATH"] = f"{prefix / 'lib'}{os.pathsep}{env['LD_LIBRARY_PATH']}"
    py = venv / "bin" / "python"
    run(
        [
            "cmake",
            "-S",
            str(src),
            "-B",
            str(bdir),
            "-G",
            "Ninja",
            f"-DCMAKE_INSTALL_PREFIX={prefix}",
            f"-DCMAKE_PREFIX_PATH={env['CMAKE_PREFIX_PATH'].replace(os.pathsep, ';')}",
            f"-DPython3_EXECUTABLE={py}",
            f"-DPYTHON_EXECUTABLE={py}",
            "-DPython3_FIND_VIRTUALENV=ONLY",
            "-DBUILD_TESTING=OFF",
            "-DCMAKE_BUILD_TYPE=Release",
        ],
        log_file,
        env,
    )
    run(["cmake", "--build", str(bdir), "--parallel", str(jobs)], log_file, env)
    run(["cmake", "--install", str(bdir)], log_file, env)
    return time.monotonic() - t0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--venv", default=os.environ.get("VENV", ".venv"), help="the venv (install prefix)")
    ap.add_argument("--jobs", type=int, default=os.cpu_count() or 2, help="parallel compile jobs")
    ap.add_argument("--force", action="store_true", help="rebuild even if the stamp matches")
    ap.add_argument("--build-dir", default=None, help="default: <venv>/.fleet-interfaces-build")
    args = ap.parse_args(argv)

    venv = Path(args.venv)
    if not venv.is_absolute():
        venv = (Path.cwd() / venv).resolve()
    if not (venv / "bin" / "python").exists():
        print(f"error: no Python at {venv}/bin/python (create the venv first)", file=sys.stderr)
        return 2
    for tool in ("cmake", "ninja"):
        if shutil.which(tool) is None:
            print(
                f"error: '{tool}' is not installed (apt-get install cmake ninja-build g++)", file=sys.stderr
            )
            return 1

    importable, ours = locate_package(venv, "nav2_msgs")
    if importable and not ours:
        log("a nav2_msgs from a ROS install is importable: using it, building nothing")
        return 0

    stamp = venv / STAMP_NAME
    digest = source_hash()
    if not args.force and importable and stamp.exists() and stamp.read_text().strip() == digest:
        log(f"interfaces up to date (stamp {stamp}), nothing to build")
        return 0

    build_root = Path(args.build_dir) if args.build_dir else venv / ".fleet-interfaces-build"
    build_root.mkdir(parents=True, exist_ok=True)
    t0 = time.monotonic()
    for name in PACKAGES:
        if name != "nav2_msgs":
            dep_importable, dep_ours = locate_package(venv, name)
            if dep_importable and not dep_ours:
                log(f"{name} from a ROS install is importable: using it")
                continue
        log(f"building {name} into {venv} ({args.jobs} jobs) ...")
        try:
            dt = build_package(name, venv, venv, build_root, args.jobs)
        except RuntimeError as exc:
            print(f"[build-interfaces] ERROR building {name}: {exc}", file=sys.stderr)
            return 1
        log(f"{name} built and installed in {dt:.1f} s")
    importable, _ = locate_package(venv, "nav2_msgs")
    if not importable:
        print("[build-interfaces] ERROR: nav2_msgs still does not import after the build", file=sys.stderr)
        return 1
    stamp.write_text(digest + "\n")
    log(f"all interfaces built in {time.monotonic() - t0:.1f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
