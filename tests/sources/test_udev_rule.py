"""systemd/90-hdeem-watch-rapl.rules opens only the DRAM zones' energy_uj to the group (CVE-2020-8694:
package/core counters stay root-only). The rule is evaluated against the kernel-layout fixture trees
the way udev matches it (SUBSYSTEM, KERNEL glob on the device name, ATTR{name} on the zone's file)."""

from __future__ import annotations

import fnmatch
import re
import shlex
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
RULE = REPO / "systemd" / "90-hdeem-watch-rapl.rules"
TERM = re.compile(r'\s*([A-Z]+(?:\{[^}]*\})?)\s*(==|\+=|=)\s*"([^"]*)"\s*,?')


def rules() -> list[list[tuple[str, str, str]]]:
    parsed = []
    for line in RULE.read_text().splitlines():
        if line.strip() and not line.lstrip().startswith("#"):
            terms = TERM.findall(line)
            assert len(terms) == line.count('"') // 2, f"unparsed rule text: {line}"
            parsed.append(terms)
    return parsed


def touched(tree: Path) -> dict[str, list[str]]:
    """sysfs files each RUN command would change, per command, for every zone device of the tree."""
    devices = tree / "devices" / "virtual" / "powercap" / "intel-rapl"
    out: dict[str, list[str]] = {}
    for zone in sorted(p for p in devices.rglob("intel-rapl:*") if p.is_dir()):
        devpath = "/" + str(zone.relative_to(tree))
        for terms in rules():
            env = {"SUBSYSTEM": "powercap", "ACTION": "add"}
            ok = True
            for key, op, value in terms:
                if op != "==":
                    continue
                if key == "KERNEL":
                    ok &= fnmatch.fnmatchcase(zone.name, value)
                elif key.startswith("ATTR{"):
                    ok &= (zone / key[5:-1]).read_text().strip() == value
                else:
                    ok &= env.get(key) == value
            if ok:
                for key, _op, value in terms:
                    if key == "RUN":
                        argv = shlex.split(value.replace("%p", devpath))
                        out.setdefault(" ".join(argv[:-1]), []).append(argv[-1])
    return out


@pytest.mark.parametrize("tree", ["powercap_4s", "powercap_multidie", "powercap_2s_swapped"])
def test_only_dram_counters_are_opened_to_the_group(powercap_trees, tree):
    """Every dram zone's energy_uj gets group hdeem-watch and mode 0440; nothing else is touched."""
    root = powercap_trees / tree
    dram = sorted("/sys/" + str(p.parent.relative_to(root) / "energy_uj")
                  for p in root.rglob("name") if p.read_text().strip() == "dram")
    changes = touched(root)
    assert set(changes) == {"/usr/bin/chgrp hdeem-watch", "/usr/bin/chmod 0440"}
    assert dram and all(sorted(files) == dram for files in changes.values())


def test_mode_gives_others_nothing_and_no_write():
    """0440: owner and group read, no write, nothing for others."""
    mode = int(re.search(r"chmod (\d+)", RULE.read_text()).group(1), 8)
    assert mode & 0o007 == 0 and mode & 0o222 == 0 and mode & 0o040
