"""Fixtures of the sources tests: the fake libhdeem (real C, built here with gcc) and the shim on it."""

from __future__ import annotations

import ctypes
import shutil
import subprocess
from pathlib import Path

import pytest

from hdeem_watch.sources.hdeem_lib import build_shim

FAKE_DIR = Path(__file__).resolve().parent / "fake_hdeem"


class FakeHdeem:
    """The built fake library: where it is, and its test controls (same process, same state)."""

    def __init__(self, lib_dir: Path, cache_dir: Path) -> None:
        self.lib_dir = lib_dir
        self.include_dir = FAKE_DIR
        self.cache_dir = cache_dir
        # load by absolute path first: the shim's dependency resolves to this very instance
        self.lib = ctypes.CDLL(str(lib_dir / "libhdeem.so"), mode=ctypes.RTLD_GLOBAL)
        self.lib.hdeem_fake_control.restype = ctypes.c_longlong
        self.lib.hdeem_fake_control.argtypes = [ctypes.c_char_p, ctypes.c_longlong]
        self.lib.hdeem_fake_set_power.argtypes = [ctypes.c_int, ctypes.c_double]
        self.lib.hdeem_fake_calls.argtypes = [ctypes.c_char_p, ctypes.c_int]

    def control(self, key: str, value: int = 0) -> int:
        return int(self.lib.hdeem_fake_control(key.encode(), value))

    def advance(self, seconds: float) -> None:
        self.control("advance_ns", int(seconds * 1e9))

    def set_power(self, sensor: int, watts: float) -> None:
        assert self.lib.hdeem_fake_set_power(sensor, watts) == 0

    def calls(self) -> list[str]:
        """The libhdeem API calls made since the last reset, in order (``"init"``, ``"start"``, ...)."""
        buf = ctypes.create_string_buffer(1 << 16)
        self.lib.hdeem_fake_calls(buf, len(buf))
        return [c for c in buf.value.decode().split(",") if c]

    def options(self, **kw) -> dict:
        opts = dict(include_dir=str(self.include_dir), lib_dir=str(self.lib_dir), cache_dir=str(self.cache_dir))
        opts.update(kw)
        return opts

    def reset(self) -> None:
        for key in ("fail_init", "fail_calls", "slow_calls", "overflow", "names_style", "deny", "blade_cap"):
            self.control(key, 0)
        self.control("run_external", -1)
        self.control("stop_ms", 20)
        self.control("slow_ms", 300)
        self.control("blade_mhz", 1003074)   # the real rates of Taurus capture 6415.txt
        self.control("vr_mhz", 98663)
        self.control("vr_offset_us", 29400)  # Score-P's time_offset_vr, -(35000 - 5600) us
        self.control("buffer_s", 8 * 3600)
        self.control("log_reset")


def _cc(args: list[str]) -> None:
    proc = subprocess.run(args, capture_output=True, text=True, check=False)
    assert proc.returncode == 0, proc.stderr


@pytest.fixture(scope="session")
def fake_hdeem_build(tmp_path_factory) -> FakeHdeem:
    """Build libhdeem.so (fake) and an empty libfreeipmi.so with gcc, once per session."""
    cc = shutil.which("gcc") or shutil.which("cc")
    assert cc, "the sources tests need a C compiler (gcc)"
    lib_dir = tmp_path_factory.mktemp("fake_hdeem_lib")
    _cc([cc, "-O2", "-Wall", "-Wextra", "-Werror", "-shared", "-fPIC", "-Wl,-soname,libhdeem.so",
         f"-I{FAKE_DIR}", "-o", str(lib_dir / "libhdeem.so"), str(FAKE_DIR / "libhdeem.c"), "-lm"])
    (lib_dir / "freeipmi.c").write_text("int hdeem_watch_fake_freeipmi(void) { return 0; }\n")
    _cc([cc, "-shared", "-fPIC", "-o", str(lib_dir / "libfreeipmi.so"), str(lib_dir / "freeipmi.c")])
    fake = FakeHdeem(lib_dir, tmp_path_factory.mktemp("shim_cache"))
    build_shim(**fake.options())  # the shim every source on the fake opens, built here once
    return fake


@pytest.fixture
def fake_hdeem(fake_hdeem_build: FakeHdeem) -> FakeHdeem:
    """The fake library with every failure switched off."""
    fake_hdeem_build.reset()
    yield fake_hdeem_build
    fake_hdeem_build.reset()
