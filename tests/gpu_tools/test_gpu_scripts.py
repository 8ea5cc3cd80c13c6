"""The GPU session's scripts on CPU: the wheel set and its install, the checkpoint parts a device
run returns, gpu_check's table, gpu_train's choices, and (slow) a stopped gpu_train resumed."""

from __future__ import annotations

import json
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO / "gpu"))  # the scripts import each other as top-level modules

import ckpt_parts  # noqa: E402
import gpu_check  # noqa: E402
import gpu_wheels  # noqa: E402
from ckpt_parts import PartsError  # noqa: E402
from gpu_wheels import WheelError  # noqa: E402

from dsnet_core.model.card import card_text  # noqa: E402


def fake_wheel(folder: Path, name: str, version: str, requires=(), tag="py3-none-any", files=None) -> Path:
    """A minimal wheel: ``files`` (path → text, default one module) and its METADATA."""
    dist = f"{name.replace('-', '_')}-{version}"
    path = folder / f"{dist}-{tag}.whl"
    files = files or {f"{name.replace('-', '_')}.py": f"VERSION = {version!r}\n"}
    meta = f"Metadata-Version: 2.1\nName: {name}\nVersion: {version}\n"
    meta += "".join(f"Requires-Dist: {r}\n" for r in requires)
    with zipfile.ZipFile(path, "w") as zf:
        for arc, text in files.items():
            zf.writestr(arc, text)
        zf.writestr(f"{dist}.dist-info/METADATA", meta)
        zf.writestr(f"{dist}.dist-info/WHEEL", f"Wheel-Version: 1.0\nRoot-Is-Purelib: true\nTag: {tag}\n")
        zf.writestr(f"{dist}.dist-info/RECORD", "")
    return path


# -- the wheel set --------------------------------------------------------------------------
def test_lock_pins_are_read_with_normalised_names(tmp_path):
    lock = tmp_path / "lock.txt"
    lock.write_text("# header\nPyYAML==6.0.4\npydantic_core==2.50.5  # comment\nruamel.yaml==0.19.1\n\n")
    assert gpu_wheels.read_pins(lock) == {
        "pyyaml": "6.0.4",
        "pydantic-core": "2.50.5",
        "ruamel-yaml": "0.19.1",
    }


def test_requirements_follow_the_target_pythons_markers(tmp_path):
    wheel = fake_wheel(
        tmp_path,
        "pkg",
        "1.0",
        requires=[
            "iniconfig>=2",
            'tomli>=2; python_version < "3.11"',
            'colorama; sys_platform == "win32"',
            'pytest-cov; extra == "testing"',
            "Typing_Extensions>=4.16.0",
        ],
    )
    assert gpu_wheels.wheel_requires(wheel, "3.12") == [
        ("iniconfig", ">=2"),
        ("typing-extensions", ">=4.16.0"),
    ]
    assert ("tomli", ">=2") in gpu_wheels.wheel_requires(wheel, "3.10")


@pytest.fixture
def fake_index(tmp_path, monkeypatch):
    """``pip download`` replaced by an index of fake wheels: zarr → numpy (machine), donfig → pyyaml
    (machine), packaging; pytest → packaging, pluggy."""
    index = {
        "zarr": ["numpy>=2.0", "donfig>=0.8", "packaging>=22"],
        "donfig": ["pyyaml"],
        "packaging": [],
        "pydantic": ["typing-extensions>=4.16"],
        "typing-extensions": [],
        "pytest": ["packaging>=24", "pluggy<2,>=1.6", "pygments>=2.15"],
        "pytest-timeout": ["pytest>=7"],
        "pluggy": [],
    }
    calls = []

    def download(pins, dest, python_version):
        calls.append(sorted(pins))
        for pin in pins:
            name, version = pin.split("==")
            fake_wheel(dest, name, version, index[name])

    monkeypatch.setattr(gpu_wheels, "_pip_download", download)
    lock = tmp_path / "lock.txt"
    lock.write_text(
        "zarr==3.1.6\ndonfig==0.8.1\npackaging==26.4\npydantic==2.14.4\ntyping_extensions==4.16.0\n"
        "pytest==9.2.0\npytest-timeout==2.4.0\npluggy==1.7.0\nnumpy==2.4.6\n"
    )
    return lock, calls


def test_download_takes_the_closure_minus_the_machines_packages(tmp_path, fake_index):
    lock, calls = fake_index
    dest = tmp_path / "wheels"
    dest.mkdir()
    stale = fake_wheel(dest, "zarr", "3.0.0")  # another version: pip would refuse two
    kept = gpu_wheels.download(dest, "3.12", lock)
    names = sorted(gpu_wheels.wheel_name(w) for w in kept)
    assert names == [
        ("donfig", "0.8.1"),
        ("packaging", "26.4"),
        ("pluggy", "1.7.0"),
        ("pydantic", "2.14.4"),
        ("pytest", "9.2.0"),
        ("pytest-timeout", "2.4.0"),
        ("typing-extensions", "4.16.0"),
        ("zarr", "3.1.6"),
    ]
    assert not stale.exists() and sorted(dest.glob("*.whl")) == sorted(kept)
    assert all("numpy" not in p and "pyyaml" not in p for c in calls for p in c)  # the machine has them
    calls.clear()
    gpu_wheels.download(dest, "3.12", lock)  # a second run fetches nothing
    assert calls == []


def test_download_names_a_missing_pin_and_who_needs_it(tmp_path, fake_index):
    lock, _ = fake_index
    lock.write_text(lock.read_text().replace("pluggy==1.7.0\n", ""))
    with pytest.raises(WheelError, match=r"no pin for pluggy \(needed by pytest\)"):
        gpu_wheels.download(tmp_path / "w", "3.12", lock)


def test_download_refuses_a_pin_that_breaks_a_requirement(tmp_path, fake_index):
    lock, _ = fake_index
    lock.write_text(lock.read_text().replace("typing_extensions==4.16.0", "typing_extensions==4.12.0"))
    with pytest.raises(
        WheelError, match=r"pydantic 2.14.4 needs typing-extensions>=4.16, the lock pins 4.12.0"
    ):
        gpu_wheels.download(tmp_path / "w", "3.12", lock)


def test_the_real_lock_pins_every_root():
    pins = gpu_wheels.read_pins()
    assert all(gpu_wheels.normalise(r) in pins for r in gpu_wheels.ROOTS)
    assert not {gpu_wheels.normalise(r) for r in gpu_wheels.ROOTS} & gpu_wheels.MACHINE_HAS


def test_install_into_a_target_imports_from_it(tmp_path, monkeypatch):
    monkeypatch.setenv("TMPDIR", str(tmp_path))
    monkeypatch.setattr(gpu_wheels.tempfile, "tempdir", None)
    wheels = tmp_path / "wheels"
    wheels.mkdir()
    fake_wheel(wheels, "dsnet-probe-a", "1.0")
    fake_wheel(wheels, "dsnet-probe-b", "2.0")
    target = gpu_wheels.install(wheels)
    assert target.parent == tmp_path and (target / gpu_wheels.COMPLETE).is_file()
    out = subprocess.run(
        [
            sys.executable,
            "-c",
            "import dsnet_probe_a, dsnet_probe_b; print(dsnet_probe_a.VERSION, dsnet_probe_b.VERSION)",
        ],
        env={"PYTHONPATH": str(target)},
        capture_output=True,
        text=True,
        check=True,
    )
    assert out.stdout.split() == ["1.0", "2.0"]
    assert gpu_wheels.install(wheels) == target  # the same set is installed once


def test_install_refuses_wheels_of_another_python(tmp_path):
    fake_wheel(tmp_path, "compiled", "1.0", tag="cp39-cp39-manylinux2014_x86_64")
    running = f"{sys.version_info[0]}.{sys.version_info[1]}"
    with pytest.raises(
        WheelError,
        match=rf"holds wheels for Python 3.9, this is {running}: run `make gpu-wheels GPU_PYVER={running}`",
    ):
        gpu_wheels.install(tmp_path)


def test_install_without_wheels_says_what_to_run(tmp_path):
    with pytest.raises(WheelError, match="no wheels: run `make gpu-wheels`"):
        gpu_wheels.install(tmp_path)


def test_unpacking_without_pip_puts_data_libraries_on_top(tmp_path):
    wheel = fake_wheel(
        tmp_path,
        "withdata",
        "1.0",
        files={"withdata/__init__.py": "", "withdata-1.0.data/purelib/extra_mod.py": "X = 1\n"},
    )
    target = tmp_path / "site"
    gpu_wheels.unpack(wheel, target)
    assert (target / "withdata" / "__init__.py").is_file() and (target / "extra_mod.py").is_file()
    assert not list(target.glob("*.data"))


# -- checkpoint parts ------------------------------------------------------------------------
@pytest.fixture
def checkpoint(tmp_path) -> Path:
    folder = tmp_path / "ckpt"
    folder.mkdir()
    (folder / "card.json").write_text(card_text({"epochs": {"semantic": 1}}))
    (folder / "metrics.csv").write_text("stage,epoch\nsemantic,1\n")
    (folder / "model.safetensors").write_bytes(bytes(range(256)) * 160)  # 40 KiB
    (folder / "train_state.safetensors").write_bytes(b"\x07" * 30_000)
    (folder / ".pending").mkdir()  # a staging folder is no part of the checkpoint
    return folder


def test_parts_round_trip_within_the_limits(tmp_path, checkpoint):
    out = tmp_path / "out"
    written = ckpt_parts.pack(checkpoint, out, part_bytes=32 * 1024)
    parts = sorted(out.glob("checkpoint.tar.*"))
    assert [p.name for p in parts] == ["checkpoint.tar.00", "checkpoint.tar.01", "checkpoint.tar.02"]
    assert all(p.stat().st_size <= 32 * 1024 for p in parts)
    assert written[-1].name == "checkpoint.json" and len(written) == 6
    assert (out / "card.json").read_text() == (checkpoint / "card.json").read_text()
    names = ckpt_parts.unpack(out, tmp_path / "back")["files"]
    assert names == ["card.json", "metrics.csv", "model.safetensors", "train_state.safetensors"]
    for name in names:
        assert (tmp_path / "back" / name).read_bytes() == (checkpoint / name).read_bytes()


def test_a_smaller_export_removes_the_parts_it_no_longer_has(tmp_path, checkpoint):
    out = tmp_path / "out"
    ckpt_parts.pack(checkpoint, out, part_bytes=32 * 1024)
    (checkpoint / "train_state.safetensors").unlink()
    ckpt_parts.pack(checkpoint, out, part_bytes=32 * 1024)
    assert sorted(p.name for p in out.glob("checkpoint.tar.*")) == ["checkpoint.tar.00", "checkpoint.tar.01"]
    assert "train_state.safetensors" not in ckpt_parts.unpack(out, tmp_path / "back")["files"]


def test_the_optimiser_state_is_left_out_of_a_checkpoint_too_large_to_carry_back(tmp_path, checkpoint):
    out = tmp_path / "out"
    (checkpoint / "train_state.json").write_text("{}")
    ckpt_parts.pack(checkpoint, out, carry_bytes=50 * 1024)  # 70 KiB with it, 40 KiB without
    manifest = ckpt_parts.unpack(out, tmp_path / "back")
    assert manifest["files"] == ["card.json", "metrics.csv", "model.safetensors"]
    assert manifest["left_out"] == {
        "files": ["train_state.json", "train_state.safetensors"],
        "why": "over 0 MiB to carry back",
    }
    assert sorted(p.name for p in (tmp_path / "back").iterdir()) == manifest["files"]


def test_a_cut_or_missing_part_is_refused_by_name(tmp_path, checkpoint):
    out = tmp_path / "out"
    ckpt_parts.pack(checkpoint, out, part_bytes=32 * 1024)
    part = out / "checkpoint.tar.01"
    part.write_bytes(part.read_bytes()[:-10])
    with pytest.raises(PartsError, match=r"checkpoint.tar.01: \d+ bytes that do not match checkpoint.json"):
        ckpt_parts.unpack(out, tmp_path / "back")
    part.unlink()
    with pytest.raises(PartsError, match=r"checkpoint.tar.01: missing"):
        ckpt_parts.unpack(out, tmp_path / "back")
    with pytest.raises(PartsError, match=r"no checkpoint\.json"):
        ckpt_parts.unpack(tmp_path, tmp_path / "back")


def test_a_checkpoint_over_the_device_limits_is_refused(tmp_path, checkpoint):
    with pytest.raises(
        PartsError, match=r"needs 10 files and 0.1 MiB, over the 8 files / 64 MiB .* narrower preset"
    ):
        ckpt_parts.pack(checkpoint, tmp_path / "out", part_bytes=12 * 1024)
    assert not (tmp_path / "out").exists()


# -- gpu_check's table, gpu_train's choices ---------------------------------------------------
def test_junit_results_become_rows(tmp_path):
    xml = tmp_path / "r.xml"
    xml.write_text(
        '<testsuites><testsuite><testcase classname="tests.gpu.test_a" name="test_x[1]" time="1.5"/>'
        '<testcase classname="tests.gpu.test_a" name="test_y" time="0.2">'
        '<failure message="assert 1 == 2&#10;more">trace</failure></testcase>'
        '<testcase classname="tests.gpu.test_b" name="test_z" time="0">'
        '<skipped message="needs CUDA"/></testcase>'
        "</testsuite></testsuites>"
    )
    assert gpu_check.junit_rows(xml) == [
        ("test_a::test_x[1]", "passed", 1.5, ""),
        ("test_a::test_y", "failed", 0.2, "assert 1 == 2"),
        ("test_b::test_z", "skipped", 0.0, "needs CUDA"),
    ]
    table = gpu_check.Table()
    table.add("test", "test_a::test_x[1]", "passed", "1.5 s")
    table.add("test", "t", "failed", failed=True)
    lines = table.render().splitlines()
    assert table.failed and len(lines) == 4 and len({len(line) for line in lines}) == 1


def test_the_widest_preset_that_fits_a_device_run_is_small():
    import gpu_train

    assert gpu_train.widest_preset() == ("small", 3_593_689)
    assert gpu_train.parse_epochs("semantic=8,offset=3,shift=2") == {
        "semantic": 8,
        "offset": 3,
        "joint": 0,
        "shift": 2,
    }
    with pytest.raises(SystemExit, match=r"expected e\.g\. semantic=8,offset=3,shift=2"):
        gpu_train.parse_epochs("semantic=8,offest=3")


@pytest.mark.slow
def test_gpu_train_stopped_after_an_epoch_resumes_from_its_parts(tmp_path):
    """Two CPU runs of gpu/gpu_train.py into one OUT: the first stops after one epoch, the
    second (no schedule flags) continues the card's schedule from the unpacked parts."""
    out = tmp_path / "out"
    base = [sys.executable, "gpu/gpu_train.py", "--out", str(out), "--device", "cpu", "--workers", "1"]
    base += ["--wheels", str(tmp_path / "no-wheels"), "--val-frames", "1", "--budget", "900"]
    first = [
        *base,
        "--preset",
        "tiny",
        "--epochs",
        "semantic=2",
        "--samples-per-epoch",
        "2",
        "--stop-after",
        "1",
    ]
    run = lambda cmd: subprocess.run(cmd, cwd=REPO, capture_output=True, text=True, timeout=900)  # noqa: E731
    done = run(first)
    assert done.returncode == 0, done.stderr[-2000:]
    assert "stopped after semantic epoch 1 (--stop-after 1)" in done.stdout
    card = json.loads((out / "card.json").read_text())
    assert card["epochs"] == {"semantic": 1} and card["training_data"]["stream"]["samples_per_epoch"] == 2
    done = run(base)
    assert done.returncode == 0, done.stderr[-2000:]
    assert "resuming" in done.stdout and "finished" in done.stdout
    card2 = json.loads((out / "card.json").read_text())
    assert card2["epochs"] == {"semantic": 2}
    assert card2["metrics"][0] == card["metrics"][0]  # the first epoch is the first run's
    assert (out / "metrics.csv").read_text().count("semantic,") == 2
