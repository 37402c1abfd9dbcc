"""The sources' settings: TOML, environment and flags reach the sources; the BMC password is guarded."""

from __future__ import annotations

import argparse
import logging
import os

import pytest

from hdeem_watch.config import load_settings
from hdeem_watch.errors import InputError
from hdeem_watch.sources.options import add_source_flags, read_password_file, source_flag_overrides


def _password(tmp_path, mode: int, text: str = "s3cret-Pw\n"):
    path = tmp_path / "bmc.pw"
    path.write_text(text)
    os.chmod(path, mode)
    return path


def test_hdeem_keys_from_toml_reach_the_source_options(tmp_path):
    """Every hdeem key in the TOML file becomes a source option; the password is read from its file."""
    pw = _password(tmp_path, 0o600)
    config = tmp_path / "d.toml"
    config.write_text(f"""source = "hdeem"
hdeem_method = "global"
hdeem_own_measurement = true
hdeem_bmc_host = "taurusi6262-bmc"
hdeem_bmc_user = "monitor"
hdeem_bmc_password_file = "{pw}"
hdeem_cflags = "-DHWS_NO_GPIO_FIELDS -O1"
hdeem_poll_interval_s = 0.5
hdeem_lib_names = "libhdeem.so.1, libhdeem.so"
hdeem_include_dir = "/opt/hdeem/include"
""")
    options = load_settings(config, env={}).source_options()
    assert options == {"method": "global", "own_measurement": True, "interval_s": 0.5,
                       "include_dir": "/opt/hdeem/include", "cflags": ("-DHWS_NO_GPIO_FIELDS", "-O1"),
                       "lib_names": ("libhdeem.so.1", "libhdeem.so"), "host": "taurusi6262-bmc",
                       "user": "monitor", "password": "s3cret-Pw"}


def test_defaults_are_passive_energy_and_the_idle_poll_interval():
    """By default: energy method, passive, read interval = the daemon's idle poll period (issue 22.12)."""
    options = load_settings(env={"HDEEM_WATCH_SOURCE": "hdeem"}).source_options()
    assert options == {"method": "energy", "own_measurement": False, "interval_s": 0.25}
    rapl = load_settings(env={"HDEEM_WATCH_SOURCE": "rapl", "HDEEM_WATCH_IDLE_POLL_INTERVAL_S": "0"})
    assert rapl.source_options() == {"interval_s": 0.1, "method": "auto"}


def test_environment_sets_the_keys():
    """HDEEM_WATCH_<KEY> variables set the same keys."""
    env = {"HDEEM_WATCH_SOURCE": "hdeem", "HDEEM_WATCH_HDEEM_METHOD": "global",
           "HDEEM_WATCH_HDEEM_OWN_MEASUREMENT": "yes", "HDEEM_WATCH_HDEEM_POLL_INTERVAL_S": "2",
           "HDEEM_WATCH_HDEEM_CFLAGS": "-DHWS_NO_GPIO_FIELDS"}
    options = load_settings(env=env).source_options()
    assert options["method"] == "global" and options["own_measurement"] is True
    assert options["interval_s"] == 2.0 and options["cflags"] == ("-DHWS_NO_GPIO_FIELDS",)


def test_flags_set_the_keys_over_the_environment():
    """The sources' flags (--rapl-root, --hdeem-*) override environment and file."""
    parser = argparse.ArgumentParser()
    add_source_flags(parser)
    args = parser.parse_args(["--rapl-root", "/tmp/pc", "--hdeem-method", "global", "--hdeem-own-measurement",
                              "--hdeem-poll-interval", "1.5", "--hdeem-bmc-host", "n1-bmc"])
    settings = load_settings(env={"HDEEM_WATCH_RAPL_ROOT": "/elsewhere"}, overrides=source_flag_overrides(args))
    assert settings.rapl_root == "/tmp/pc" and settings.hdeem_method == "global"
    assert settings.hdeem_own_measurement is True and settings.hdeem_poll_interval_s == 1.5
    assert settings.hdeem_bmc_host == "n1-bmc"
    none_given = load_settings(env={}, overrides=source_flag_overrides(parser.parse_args([])))
    assert none_given.hdeem_own_measurement is False and none_given.rapl_root is None


@pytest.mark.parametrize(("key", "value", "what"), [
    ("hdeem_method", "samples", "expected one of energy, global"),
    ("rapl_method", "msr", "expected one of auto, powercap, perf"),
    ("hdeem_poll_interval_s", "0", "expected a number > 0"),
    ("hdeem_cflags", "'-DX", "No closing quotation"),
])
def test_bad_values_name_key_and_value(key, value, what):
    """A bad value is an InputError naming the key, the value and what was expected."""
    with pytest.raises(InputError, match=what) as info:
        load_settings(env={f"HDEEM_WATCH_{key.upper()}": value})
    assert key in str(info.value)


def test_user_or_password_without_host_is_rejected():
    """Out-of-band credentials without hdeem_bmc_host are a mistake, not silently in-band."""
    with pytest.raises(InputError, match="need hdeem_bmc_host"):
        load_settings(env={"HDEEM_WATCH_HDEEM_BMC_USER": "monitor"})


@pytest.mark.parametrize("mode", [0o644, 0o640, 0o604, 0o660])
def test_password_file_readable_by_others_is_refused_without_showing_it(tmp_path, mode, caplog):
    """A password file group/others can read is refused; the message names the file and mode, never
    the password, and nothing is logged."""
    pw = _password(tmp_path, mode)
    settings = load_settings(env={"HDEEM_WATCH_SOURCE": "hdeem", "HDEEM_WATCH_HDEEM_BMC_HOST": "n1-bmc",
                                  "HDEEM_WATCH_HDEEM_BMC_PASSWORD_FILE": str(pw)})
    with caplog.at_level(logging.DEBUG), pytest.raises(InputError) as info:
        settings.source_options()
    message = str(info.value)
    assert f"{mode:04o}" in message and str(pw) in message and "chmod 600" in message
    assert "s3cret" not in message and "s3cret" not in caplog.text
    assert "s3cret" not in repr(settings)


def test_password_file_problems(tmp_path):
    """Missing, empty, a symlink or a directory: one line each, never the content."""
    with pytest.raises(InputError, match="cannot open"):
        read_password_file(str(tmp_path / "none"))
    empty = _password(tmp_path, 0o600, "\n")
    with pytest.raises(InputError, match="empty"):
        read_password_file(str(empty))
    good = _password(tmp_path, 0o400)
    assert read_password_file(str(good)) == "s3cret-Pw"
    link = tmp_path / "link"
    link.symlink_to(good)
    with pytest.raises(InputError, match="cannot open"):
        read_password_file(str(link))
