"""Wheels for a GPU machine without a package registry: download them here, install them there.

The GPU machine has Python 3.12 with a CUDA torch, numpy, scipy, numba, pyarrow, safetensors,
typer, rich, fsspec and pyyaml (:data:`MACHINE_HAS`, with their own dependencies) and nothing else
of this project's needs. ``download`` (``make gpu-wheels``, on a machine with PyPI) fetches the
rest — the closure of :data:`ROOTS` under the wheels' own ``Requires-Dist``, minus what the machine
has, every version pinned by ``constraints/lock.txt`` — for the GPU machine's Python and platform
into an ignored folder that travels with the working tree. ``activate`` (``make gpu-check`` and
``make gpu-train``, there) installs them with ``pip install --no-index --no-deps --target`` into a
temporary folder and puts it first on ``sys.path`` and ``PYTHONPATH``; the machine's own torch and
site-packages are never touched, and no virtual environment is made.

Run: ``python gpu/gpu_wheels.py download [--dest gpu-wheels] [--python-version 3.12]``;
``python gpu/gpu_wheels.py install [--wheels gpu-wheels]`` prints the target folder.
"""

from __future__ import annotations

import argparse
import hashlib
import os
import re
import shutil
import subprocess
import sys
import tempfile
import zipfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
LOCK = ROOT / "constraints" / "lock.txt"
DEFAULT_WHEELS = ROOT / "gpu-wheels"
ROOTS = ("zarr", "pydantic", "pytest", "pytest-timeout")
"""What the GPU check and training need beyond the machine's packages: the run store (zarr, its
codecs), the typed configs (pydantic) and the test runner."""
MACHINE_HAS = frozenset(
    {
        # the packages the GPU machine is known to have
        *("torch", "numpy", "scipy", "numba", "pyarrow", "safetensors"),
        *("typer", "rich", "fsspec", "pyyaml"),
        # and theirs (typing-extensions is shipped anyway: pydantic needs a recent one)
        *("llvmlite", "click", "shellingham", "markdown-it-py", "mdurl", "pygments", "annotated-doc"),
        *("sympy", "mpmath", "networkx", "jinja2", "markupsafe", "filelock", "setuptools", "triton"),
    }
)
PLATFORMS = (
    "manylinux_2_28_x86_64",
    "manylinux_2_27_x86_64",
    "manylinux_2_17_x86_64",
    "manylinux2014_x86_64",
    "manylinux1_x86_64",
)
TRAVEL_LIMIT = 64 * 2**20
"""What travels to the GPU machine (working tree + carried folders), bytes."""
COMPLETE = ".dsnet-complete"


class WheelError(RuntimeError):
    """A wheel set that cannot be made or installed; the message names the folder and the fix."""


def normalise(name: str) -> str:
    """PEP 503 name: lower case, runs of ``-_.`` as one ``-``."""
    return re.sub(r"[-_.]+", "-", name).lower()


def read_pins(lock: Path = LOCK) -> dict[str, str]:
    """``name -> version`` of every ``name==version`` line of the lock file (names normalised)."""
    pins = {}
    for line in lock.read_text().splitlines():
        line = line.split("#", 1)[0].strip()
        if "==" in line:
            name, version = line.split("==", 1)
            pins[normalise(name)] = version.strip()
    return pins


def _packaging():
    """``packaging``'s requirements and markers (the installed one, else pip's vendored copy)."""
    try:
        from packaging.requirements import Requirement
    except ImportError:  # a bare interpreter: pip carries its own copy
        from pip._vendor.packaging.requirements import Requirement
    return Requirement


def marker_env(python_version: str) -> dict[str, str]:
    """The environment markers of CPython ``python_version`` on x86-64 Linux."""
    return {
        "python_version": python_version,
        "python_full_version": f"{python_version}.0",
        "sys_platform": "linux",
        "platform_system": "Linux",
        "platform_machine": "x86_64",
        "os_name": "posix",
        "implementation_name": "cpython",
        "platform_python_implementation": "CPython",
        "extra": "",
    }


def wheel_requires(wheel: Path, python_version: str) -> list[tuple[str, str]]:
    """``(name, specifier)`` of the wheel's ``Requires-Dist`` that apply on the target Python
    (markers evaluated, extras left out)."""
    requirement = _packaging()
    with zipfile.ZipFile(wheel) as zf:
        meta = next(n for n in zf.namelist() if n.endswith(".dist-info/METADATA"))
        text = zf.read(meta).decode()
    out = []
    env = marker_env(python_version)
    for line in text.splitlines():
        if not line.startswith("Requires-Dist:"):
            continue
        req = requirement(line.split(":", 1)[1].strip())
        if req.marker is None or req.marker.evaluate(env):
            out.append((normalise(req.name), str(req.specifier)))
    return out


def wheel_name(wheel: Path) -> tuple[str, str]:
    """``(normalised name, version)`` from a wheel's file name."""
    name, version = wheel.name.split("-")[:2]
    return normalise(name), version


def _pip_download(pins: list[str], dest: Path, python_version: str) -> None:
    abi = "cp" + python_version.replace(".", "")
    cmd = [sys.executable, "-m", "pip", "download", "-q", "--no-deps", "--only-binary=:all:"]
    cmd += ["--python-version", python_version, "--implementation", "cp", "--abi", abi, "--abi", "abi3"]
    cmd += ["--abi", "none"]
    for p in PLATFORMS:
        cmd += ["--platform", p]
    subprocess.run([*cmd, "-d", str(dest), *pins], check=True)


def download(dest: Path = DEFAULT_WHEELS, python_version: str = "3.12", lock: Path = LOCK) -> list[Path]:
    """Fetch the closure of :data:`ROOTS` (minus :data:`MACHINE_HAS`) pinned by ``lock`` into ``dest``.

    Wheels of other versions or packages left in ``dest`` are removed (pip refuses two versions
    of one package). Every requirement of a shipped wheel must be met by a pin (checked against
    its specifier) or by the machine.

    Raises:
        WheelError: a needed package has no pin in the lock file, or its pin breaks a requirement.
    """
    pins = read_pins(lock)
    dest.mkdir(parents=True, exist_ok=True)
    wanted: dict[str, str] = {}
    todo = [normalise(r) for r in ROOTS]
    needed_by: dict[str, str] = {}
    while todo:
        missing = [n for n in todo if n not in pins]
        if missing:
            who = ", ".join(f"{n} (needed by {needed_by.get(n, 'the GPU scripts')})" for n in missing)
            raise WheelError(f"{lock}: no pin for {who}: add `name==version` lines")
        for n in todo:
            wanted[n] = pins[n]
        have = {wheel_name(w) for w in dest.glob("*.whl")}
        fetch = [f"{n}=={pins[n]}" for n in todo if (n, pins[n]) not in have]
        if fetch:
            _pip_download(fetch, dest, python_version)
        found = {wheel_name(w): w for w in dest.glob("*.whl")}
        nxt = []
        for n in todo:
            wheel = found.get((n, pins[n]))
            if wheel is None:
                raise WheelError(f"{dest}: pip downloaded no wheel of {n}=={pins[n]}")
            for dep, spec in wheel_requires(wheel, python_version):
                if dep in MACHINE_HAS:
                    continue
                if dep in pins and spec and not _satisfies(pins[dep], spec):
                    raise WheelError(f"{lock}: {n} {pins[n]} needs {dep}{spec}, the lock pins {pins[dep]}")
                if dep not in wanted and dep not in nxt:
                    nxt.append(dep)
                    needed_by[dep] = n
        todo = nxt
    keep = []
    for wheel in sorted(dest.glob("*.whl")):
        name, version = wheel_name(wheel)
        if wanted.get(name) == version:
            keep.append(wheel)
        else:
            wheel.unlink()
    return keep


def _satisfies(version: str, spec: str) -> bool:
    requirement = _packaging()
    return requirement(f"x{spec}").specifier.contains(version, prereleases=True)


def tree_bytes(root: Path = ROOT) -> int:
    """Bytes of the files that travel with the working tree: tracked, and untracked not ignored."""
    out = subprocess.run(
        ["git", "-C", str(root), "ls-files", "-z", "--cached", "--others", "--exclude-standard"],
        check=True,
        capture_output=True,
    ).stdout
    names = {n for n in out.decode().split("\0") if n}
    return sum((root / n).stat().st_size for n in names if (root / n).is_file())


# -- on the GPU machine --------------------------------------------------------------------------
def wheel_python(wheels: list[Path]) -> str | None:
    """The CPython version (``"3.12"``) the compiled wheels were built for; None if all are pure."""
    for w in wheels:
        m = re.search(r"-cp(\d)(\d+)-", w.name)
        if m:
            return f"{m.group(1)}.{m.group(2)}"
    return None


def install(wheels_dir: Path = DEFAULT_WHEELS, python: str = sys.executable) -> Path:
    """Install every wheel of ``wheels_dir`` into a temporary target folder (reused while the same
    wheels are installed: a folder per content hash, marked complete last).

    ``pip install --no-index --no-deps --target``; where ``python`` has no pip, the wheels are
    unpacked (they are plain zip files; their ``.data`` libraries are moved to the top).

    Raises:
        WheelError: no wheels, or wheels for another Python than ``python``'s.
    """
    wheels = sorted(Path(wheels_dir).glob("*.whl"))
    if not wheels:
        raise WheelError(f"{wheels_dir}: no wheels: run `make gpu-wheels` on a machine with PyPI first")
    built = wheel_python(wheels)
    running = subprocess.run(
        [python, "-c", "import sys; print(f'{sys.version_info[0]}.{sys.version_info[1]}')"],
        check=True,
        capture_output=True,
        text=True,
    ).stdout.strip()
    if built is not None and built != running:
        raise WheelError(
            f"{wheels_dir} holds wheels for Python {built}, this is {running}: "
            f"run `make gpu-wheels GPU_PYVER={running}` where PyPI is reachable"
        )
    key = hashlib.sha256("".join(f"{w.name}:{w.stat().st_size};" for w in wheels).encode()).hexdigest()
    target = Path(tempfile.gettempdir()) / f"dsnet-gpu-site-{running}-{key[:12]}"
    if (target / COMPLETE).is_file():
        return target
    staging = Path(tempfile.mkdtemp(prefix=target.name + ".", dir=target.parent))
    has_pip = subprocess.run([python, "-m", "pip", "--version"], capture_output=True).returncode == 0
    if has_pip:
        cmd = [python, "-m", "pip", "install", "-q", "--no-index", "--no-deps", "--no-cache-dir"]
        cmd += ["--disable-pip-version-check", "--target", str(staging), *map(str, wheels)]
        subprocess.run(cmd, check=True)
    else:
        for w in wheels:
            unpack(w, staging)
    (staging / COMPLETE).write_text("\n".join(w.name for w in wheels) + "\n")
    try:
        os.replace(staging, target)
    except OSError:  # another process installed the same set meanwhile
        shutil.rmtree(staging, ignore_errors=True)
    return target


def unpack(wheel: Path, target: Path) -> None:
    """Install one wheel by unpacking it (no pip): ``*.data/purelib`` and ``platlib`` go to the top,
    scripts and headers are left out."""
    with zipfile.ZipFile(wheel) as zf:
        zf.extractall(target)
    for data in target.glob("*.data"):
        for lib in ("purelib", "platlib"):
            if (data / lib).is_dir():
                for item in (data / lib).iterdir():
                    os.replace(item, target / item.name)
        shutil.rmtree(data)


def activate(wheels_dir: Path = DEFAULT_WHEELS) -> Path | None:
    """Install the wheels (if the folder has any) and put them and the repository first on
    ``sys.path`` and ``PYTHONPATH`` (child processes see them too). Returns the target folder."""
    target = install(wheels_dir) if any(Path(wheels_dir).glob("*.whl")) else None
    paths = [str(target)] if target else []
    paths.append(str(ROOT))
    for p in reversed(paths):
        if p not in sys.path:
            sys.path.insert(0, p)
    old = os.environ.get("PYTHONPATH")
    os.environ["PYTHONPATH"] = os.pathsep.join(paths + ([old] if old else []))
    return target


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    d = sub.add_parser("download", help="fetch the wheels (needs PyPI)")
    d.add_argument("--dest", type=Path, default=DEFAULT_WHEELS)
    d.add_argument("--python-version", default="3.12")
    i = sub.add_parser("install", help="install them into a temporary target; prints its path")
    i.add_argument("--wheels", type=Path, default=DEFAULT_WHEELS)
    args = ap.parse_args()
    try:
        if args.cmd == "install":
            print(install(args.wheels))
            return
        wheels = download(args.dest, args.python_version)
    except WheelError as exc:
        sys.exit(f"error: {exc}")
    size = sum(w.stat().st_size for w in wheels)
    tree = tree_bytes()
    for w in wheels:
        print(f"  {w.stat().st_size / 2**20:7.2f} MiB  {w.name}")
    total = tree + size
    print(
        f"{len(wheels)} wheels for Python {args.python_version}: {size / 2**20:.1f} MiB in {args.dest}; "
        f"with the working tree ({tree / 2**20:.1f} MiB) {total / 2**20:.1f} MiB travel "
        f"(limit {TRAVEL_LIMIT / 2**20:.0f} MiB)"
    )
    if total > TRAVEL_LIMIT:
        sys.exit(
            f"error: {total / 2**20:.1f} MiB would travel, over the {TRAVEL_LIMIT / 2**20:.0f} MiB limit"
        )


if __name__ == "__main__":
    main()
